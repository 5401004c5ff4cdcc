"""The house rules of issue #14, checked: folders by role, no arrow from io/ to the
estimators, no import cycles, the COLMAP defaults a preset that user options override
field by field, the CLI's choices taken from the library; and issue #30's: no function over
80 lines without a reason in a comment, no module over 600 lines, and the modules split by role
keeping the names that moved."""

import ast
import json
from pathlib import Path

import pytest

from cli_helpers import run

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "rotgraph"
COLMAP = ROOT / "datasets" / "colmap_synthetic"


def _module_name(path: Path) -> str:
    if path.is_relative_to(ROOT / "cli"):
        parts = ("rotgraph", "cli") + path.relative_to(ROOT / "cli").with_suffix("").parts
    else:
        parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(p for p in parts if p != "__init__")


def _imports() -> dict[str, set[str]]:
    """Module -> the rotgraph modules it imports (at any depth of its code)."""
    graph: dict[str, set[str]] = {}
    for path in list(PACKAGE.rglob("*.py")) + list((ROOT / "cli").rglob("*.py")):
        name = _module_name(path)
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        out = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[: len(base) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            out.update(t for t in targets if t.startswith("rotgraph"))
        graph[name] = out
    modules = set(graph)
    return {m: {t for t in ts if t in modules and t != m} for m, ts in graph.items()}


def test_io_never_imports_an_estimator_and_estimators_never_import_io_or_cli():
    imports = _imports()
    for mod, targets in imports.items():
        if mod.startswith("rotgraph.io"):
            assert not [t for t in targets if t.startswith(("rotgraph.estimators", "rotgraph.pipeline", "rotgraph.cli"))], mod
        if mod.startswith("rotgraph.estimators"):
            assert not [t for t in targets if t.startswith(("rotgraph.io", "rotgraph.pipeline", "rotgraph.cli"))], mod
        if not mod.startswith("rotgraph.cli") and mod != "rotgraph.__main__":  # the entry points
            assert not [t for t in targets if t.startswith("rotgraph.cli")], mod


def test_no_import_cycles():
    imports = _imports()
    state: dict[str, int] = {}

    def visit(m, stack):
        state[m] = 1
        for t in sorted(imports.get(m, ())):
            # a package's __init__ importing its own submodules is not a cycle of roles
            if state.get(t) == 1:
                raise AssertionError(" -> ".join(stack + [m, t]))
            if t not in state:
                visit(t, stack + [m])
        state[m] = 2

    for m in sorted(imports):
        if m not in state and m != "rotgraph":
            visit(m, [])


def test_colmap_preset_is_kept_when_the_user_sets_another_option(tmp_path):
    """Regression (#14): any option on a COLMAP project used to drop the COLMAP defaults
    (GLOMAP's 5 L1 iterations; inlier-count weights, which give way to the pairs' rotation
    information when that is used, #16): only the options set change."""
    r = run("solve", COLMAP, "-o", tmp_path / "r.csv", "--refine", "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    opts = out["options"]
    assert opts["refine"] is True and opts["use_weights"] is False and opts["l1_iterations"] == 5
    assert opts["use_information"] is True and out["diagnostics"]["information"]["used"] is True
    r = run("solve", COLMAP, "-o", tmp_path / "r.csv", "--no-use-information", "--json")
    out = json.loads(r.stdout)
    opts = out["options"]
    assert opts["use_weights"] is True and opts["l1_iterations"] == 5 and "information" not in out["diagnostics"]
    r = run("solve", COLMAP, "-o", tmp_path / "r.csv", "--use-weights", "--json")
    opts = json.loads(r.stdout)["options"]
    assert opts["use_weights"] is True and opts["use_information"] is True and opts["l1_iterations"] == 5
    r = run("solve", ROOT / "datasets" / "synthetic" / "edges.txt", "-o", tmp_path / "s.csv", "--refine", "--json")
    opts = json.loads(r.stdout)["options"]
    assert opts["refine"] is True and opts["use_weights"] is False and opts["l1_iterations"] == 10


def test_default_options_by_format():
    from rotgraph.estimators.types import SolveOptions
    from rotgraph.pipeline.solve import default_options

    assert default_options("rotgraph") == SolveOptions() == default_options(None)
    assert default_options("colmap") == SolveOptions(use_weights=False, l1_iterations=5)
    assert default_options("colmap", use_information=False) == SolveOptions(use_weights=True, l1_iterations=5, use_information=False)
    assert default_options("colmap", use_weights=True).use_weights is True
    with pytest.raises(ValueError, match="unknown method"):
        default_options("colmap", method="nope")


def test_cli_choices_come_from_the_library():
    from rotgraph import choices
    from rotgraph.cli.main import cli

    solve = cli.commands["solve"]
    batch = cli.commands["batch"]
    by_name = {p.name: p for p in solve.params}
    assert tuple(by_name["method"].type.choices) == choices.METHODS == tuple(m.name for m in choices.METHOD_TABLE)
    assert all(f"{m.name}: {m.help}" in by_name["method"].help for m in choices.METHOD_TABLE)
    assert tuple(by_name["loss"].type.choices) == choices.LOSSES
    assert tuple(by_name["fmt"].type.choices) == choices.EDGE_FORMATS
    # every solver option of solve is one of batch too (--certify: solve only, for now; the
    # per-input files --rigs, --extrinsics-out, --frames-out: solve only; solve's --workers,
    # --scheduler, --memory-limit, --blocks spread one problem over a cluster, batch's own
    # --workers / --scheduler many)
    per_input = ("input_path", "output", "output_format", "edges_out", "certify_", "as_json", "quiet", "rigs_file", "extrinsics_out", "frames_out",
                 "gravity_file", "gravity_sigma", "workers", "scheduler", "memory_limit", "blocks")
    shared = [p.name for p in solve.params if p.name not in per_input]
    assert [p.name for p in batch.params if p.name in shared] == shared


def test_python_dash_m_rotgraph():
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "rotgraph", "--version"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "rotgraph" in r.stdout


def test_import_rotgraph_changes_nothing_outside_the_package():
    """Issue #30 item 6: ``import rotgraph`` installs no import hook and adds nothing to
    ``sys.path`` (the source-checkout lookup of ``cli/`` is done by ``python -m rotgraph``
    and the tests' conftest, not by the package); every public name resolves."""
    import subprocess
    import sys

    code = ("import sys; hooks, path = list(sys.meta_path), list(sys.path); import rotgraph; "
            "assert sys.meta_path == hooks and sys.path == path, (sys.meta_path, hooks); "
            "[getattr(rotgraph, name) for name in rotgraph.__all__]; "
            "assert sys.meta_path == hooks; print('ok')")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


def test_the_command_line_from_a_source_checkout_without_an_install(tmp_path):
    """``python -m rotgraph`` in a copy of the source tree, with no rotgraph installed on the
    path but the copy: the top-level ``cli/`` is found (rotgraph.source_checkout)."""
    import shutil
    import subprocess
    import sys

    for part in ("rotgraph", "cli"):
        shutil.copytree(ROOT / part, tmp_path / part, ignore=shutil.ignore_patterns("__pycache__"))
    # -I: no user site, no PYTHONPATH; -m puts the working directory first: the copy, not an installed rotgraph
    code = ("import sys, runpy; sys.path.insert(0, '.'); sys.argv = ['rotgraph', '--version']; "
            "runpy.run_module('rotgraph', run_name='__main__')")
    r = subprocess.run([sys.executable, "-I", "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 0 and "rotgraph" in r.stdout, r.stderr
    code = ("import sys; sys.path.insert(0, '.'); from rotgraph.source_checkout import find_cli; find_cli(); "
            "import rotgraph.cli.main as m; print(m.__file__)")
    r = subprocess.run([sys.executable, "-I", "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.stdout.strip() == str(tmp_path / "cli" / "main.py"), r.stdout + r.stderr
    r = subprocess.run([sys.executable, "-I", "-c", "import sys; sys.path.insert(0, '.'); import rotgraph; "
                        "print(rotgraph.__file__)"], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert r.stdout.strip().startswith(str(tmp_path)), r.stdout + r.stderr


def test_the_readme_layout_names_every_module():
    """Issue #30 item 6: README's layout table names every module of the package (its file
    name without .py, in the row of its folder), so that it cannot drift from the tree."""
    import re

    text = (ROOT / "README.md").read_text()
    table = text[text.index("| where | what |"):]
    table = table[: table.index("\n\n")]
    rows = {}
    for line in table.splitlines()[2:]:
        where = line.split("|")[1]
        folder = re.match(r"\s*`rotgraph/(\w+)/", where)
        rows.setdefault(folder.group(1) if folder else "", []).append(line)
    missing = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "__init__.py" and path.parent != PACKAGE:
            continue
        folder = "" if path.parent == PACKAGE else path.parent.name
        name = path.name if path.parent == PACKAGE else path.stem
        if not any(re.search(rf"`(rotgraph/)?{re.escape(name)}`|`{re.escape(name)}(\.py)?`|{re.escape(name)}`", r) or
                   (path.parent == PACKAGE and f"{path.name}" in r) for r in rows.get(folder, [])):
            missing.append(str(path.relative_to(ROOT)))
    assert not missing, f"README's layout table does not name {missing}"


#: Issue #30: no function longer than this many body lines (from the first statement after
#: the docstring to the end) without a reason: a ``# long: why`` comment on its ``def`` line
#: or the line before (before its decorators, for a decorated one).
MAX_BODY_LINES = 80
#: Long functions whose split is waiting for another change (module.qualname). An entry
#: that has dropped to MAX_BODY_LINES or below fails too: take it off the list.
PENDING_SPLIT: set[str] = set()


def _function_lengths() -> dict[str, tuple[int, bool, str]]:
    """module.qualname -> (body lines, has a ``# long:`` reason, path:line) of every function
    and method of rotgraph/ and cli/ (nested ones too, under their outer function's name)."""
    out = {}
    for path in sorted(list(PACKAGE.rglob("*.py")) + list((ROOT / "cli").rglob("*.py"))):
        text = path.read_text()
        lines = text.splitlines()

        def reason(lineno: int) -> bool:  # a "# long: <why>" comment on line ``lineno`` (1-based)
            if not 1 <= lineno <= len(lines) or "# long:" not in lines[lineno - 1]:
                return False
            return bool(lines[lineno - 1].split("# long:", 1)[1].strip())

        def visit(node, prefix):
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.ClassDef):
                    visit(child, f"{prefix}{child.name}.")
                elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    body = child.body
                    if (isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                            and isinstance(body[0].value.value, str)):
                        body = body[1:]  # the docstring
                    n = child.end_lineno - body[0].lineno + 1 if body else 0
                    first = min([child.lineno] + [d.lineno for d in child.decorator_list])
                    ok = reason(child.lineno) or reason(child.lineno - 1) or reason(first - 1)
                    name = f"{_module_name(path)}.{prefix}{child.name}"
                    out[name] = (max(n, out.get(name, (0,))[0]), ok, f"{path.relative_to(ROOT)}:{child.lineno}")
                    visit(child, f"{prefix}{child.name}.")
                else:
                    visit(child, prefix)

        visit(ast.parse(text), "")
    return out


def test_no_function_is_long_without_a_reason():
    """Issue #30: a function over MAX_BODY_LINES body lines reads as its steps only in
    named helpers; a longer one says why (``# long: ...``) or is in PENDING_SPLIT."""
    lengths = _function_lengths()
    long = [f"{where} {name}: {n} lines" for name, (n, ok, where) in sorted(lengths.items())
            if n > MAX_BODY_LINES and not ok and name not in PENDING_SPLIT]
    assert not long, f"functions over {MAX_BODY_LINES} body lines without a '# long: <reason>' comment: {long}"
    done = sorted(name for name in PENDING_SPLIT if name not in lengths or lengths[name][0] <= MAX_BODY_LINES)
    assert not done, f"PENDING_SPLIT entries now at most {MAX_BODY_LINES} lines (or gone): take them off the list: {done}"


#: Issue #30: no module of rotgraph/ or cli/ longer than this many lines: a longer one holds
#: more than one role; split it by role (the old module re-exporting what moved).
MAX_MODULE_LINES = 600
#: Modules waiting for their split (path: the reason it cannot be split yet). An entry that
#: has dropped to MAX_MODULE_LINES or below fails too: take it off the list.
PENDING_MODULE_SPLIT: dict[str, str] = {}


def test_no_module_is_longer_than_the_limit():
    lengths = {str(p.relative_to(ROOT)): len(p.read_text().splitlines())
               for p in sorted(list(PACKAGE.rglob("*.py")) + list((ROOT / "cli").rglob("*.py")))}
    long = [f"{p}: {n} lines" for p, n in lengths.items() if n > MAX_MODULE_LINES and p not in PENDING_MODULE_SPLIT]
    assert not long, f"modules over {MAX_MODULE_LINES} lines (split them by role): {long}"
    done = sorted(p for p in PENDING_MODULE_SPLIT if lengths.get(p, 0) <= MAX_MODULE_LINES)
    assert not done, f"PENDING_MODULE_SPLIT entries now at most {MAX_MODULE_LINES} lines (or gone): take them off the list: {done}"


#: The names that moved when a module was split by role (#30): its old module still has each
#: of them, the very object of the new home, so that the public import paths keep working.
MOVED = {
    "rotgraph.so3": {
        "rotgraph.so3_rows": ("qmul_rows", "qconj_rows", "qlog_rows", "qexp_rows", "positive_w_rows", "left_matrix_rows",
                              "matrix_rows", "matmul_rows", "congruence_rows", "quaternion_rows_from_matrices",
                              "matrices_from_quaternion_rows", "right_jacobian_inverse_rows",
                              "right_jacobian_inverse_coefficient", "rotation_errors", "QMUL_TABLE", "OUTER_MAX",
                              "MATMUL_ROWS_BLOCK"),
        "rotgraph.so3_checks": ("check_rotations", "check_quaternions", "check_quaternion_rows", "is_rotation", "project_to_so3",
                                "ROTATION_TOL", "QUATERNION_ZERO", "QUATERNION_UNIT_TOL", "QUATERNION_BLOCK"),
    },
    "rotgraph.io.tables": {
        "rotgraph.io.table_lines": ("first_data_line", "simple_line_breaks"),
        "rotgraph.io.table_columns": ("INT64_MAX", "Table", "unique", "resolve_ids"),
        "rotgraph.io.table_stream": ("read_table_file", "STREAM_BLOCK"),
    },
    "rotgraph.io.edges": {
        "rotgraph.io.edges_binary": ("BINARY_COLUMNS", "BINARY_REQUIRED", "read_parquet_part"),
        "rotgraph.io.graphs": ("INFORMATION_TEXT_COLUMNS", "INFORMATION_CSV_COLUMNS"),
    },
    "rotgraph.io.text": {
        "rotgraph.io.atomic": ("STDOUT", "atomic_write", "output_group", "writes_to_stdout", "write_error"),
        "rotgraph.io.outputs": ("OWN_SIGNATURES", "PLOT_CREATOR", "check_outputs", "check_replaceable", "probe_folder",
                                "is_rotgraph_output", "input_datasets", "refuse_input_dataset"),
    },
    "rotgraph.io.colmap": {"rotgraph.io.colmap_tables": ("pair_ids",)},
    "rotgraph.pipeline.blocks": {"rotgraph.pipeline.blocks_irls": ("sample", "weighted_state", "state_rhs", "state_matvec",
                                                                   "weighted_degrees", "finish", "State"),
                                 "rotgraph.pipeline.partition": ("partition", "holders", "PARTITION_DEGREE", "PARTITIONERS")},
}


@pytest.mark.parametrize("old", sorted(MOVED))
def test_split_modules_keep_the_names_that_moved(old):
    import importlib

    module = importlib.import_module(old)
    for new, names in MOVED[old].items():
        home = importlib.import_module(new)
        for name in names:
            assert getattr(module, name) is getattr(home, name), f"{old}.{name} is not {new}.{name}"
    missing = [n for n in getattr(module, "__all__", ()) if not hasattr(module, n)]
    assert not missing, f"{old}.__all__ names what it lacks: {missing}"
