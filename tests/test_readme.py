"""README's Python API example runs as it is (from the repository root, here a copy)."""

import os
import re
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_readme_python_api_example_runs(tmp_path, capsys):
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Python API"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    shutil.copytree(ROOT / "datasets", tmp_path / "datasets")  # the example writes rotations.csv
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        exec(compile(code, "README.md", "exec"), {"__name__": "readme"})
    finally:
        os.chdir(cwd)
    out = capsys.readouterr().out
    assert "median error" in out and "component(s)" in out
    assert (tmp_path / "rotations.csv").read_text().startswith("id,name,qw,qx,qy,qz\n")
