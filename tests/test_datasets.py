"""The bundled datasets do what their READMEs say (the numbers quoted there are measured)."""

import re
from pathlib import Path

import numpy as np

from rotgraph.estimators.rotation_averaging import average_rotations
from rotgraph.evaluate import compare_rotations
from rotgraph.pipeline.read import read_view_graph
from rotgraph.pipeline.solve import default_options

ROOT = Path(__file__).resolve().parents[1]


def test_colmap_synthetic_readme_numbers():
    folder = ROOT / "datasets" / "colmap_synthetic"
    text = (folder / "README.md").read_text()
    line = next(s for s in text.splitlines() if s.startswith("Expected"))
    n_ok, n_all, n_out, median, mean, worst = map(float, re.search(
        r"(\d+)/(\d+) images, (\d+) outlier edges, median error ([\d.]+)°, mean ([\d.]+)°, max ([\d.]+)°", line).groups())
    graph = read_view_graph(folder)
    res = average_rotations(graph, default_options(graph.format))
    ev = compare_rotations(res.cam_from_world, graph.gt_cam_from_world)
    assert (res.n_solved, graph.n_nodes, res.n_outliers) == (n_ok, n_all, n_out)
    assert np.round([ev.median, ev.mean], 3).tolist() == [median, mean] and round(ev.max, 2) == worst
