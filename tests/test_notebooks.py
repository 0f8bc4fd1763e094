"""The notebooks in notebooks/ run top to bottom, are stored without outputs and use only the public API.

Each notebook runs in a fresh kernel started from this interpreter (a kernelspec written to a temporary
JUPYTER_PATH, so the kernel has the same environment as the tests whatever PATH says), with cwd =
notebooks/ and JAXDEPTH_SHARED_DATA pointing at the shared data. The executed copy lives in memory only;
the stored notebook is never rewritten. Notebooks that need the shared data skip locally and fail under CI
when it is missing (``require_shared``).
"""

from __future__ import annotations

import json
import os
import re
import sys

import pytest

from conftest import REPO, require_shared

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
pytest.importorskip("matplotlib")

NOTEBOOKS = REPO / "notebooks"
KERNEL = "jaxdepth-tests"

#: notebook -> the shared data it reads (path parts under shared/data)
CASES = {
    "01_four_steps_kitti.ipynb": ("kitti", "drive_0001_frame05"),
    "02_nuscenes_surround.ipynb": ("nuscenes", "sample"),
    "03_parameter_sweep.ipynb": ("kitti", "drive_0001_frame05"),
}

#: figures each notebook must draw (image/png outputs)
MIN_FIGURES = {"01_four_steps_kitti.ipynb": 6, "02_nuscenes_surround.ipynb": 2, "03_parameter_sweep.ipynb": 1}


def _read(name: str):
    return nbformat.read(NOTEBOOKS / name, as_version=4)


def test_every_notebook_is_tested():
    assert sorted(p.name for p in NOTEBOOKS.glob("*.ipynb")) == sorted(CASES)


@pytest.mark.parametrize("name", sorted(CASES))
def test_stored_without_outputs_and_valid(name):
    nb = _read(name)
    nbformat.validate(nb)
    for i, cell in enumerate(nb.cells):
        if cell.cell_type == "code":
            assert cell.outputs == [], f"{name} cell {i}: outputs are stored (strip them)"
            assert cell.execution_count is None, f"{name} cell {i}: execution count {cell.execution_count} stored"
    assert nb.metadata.get("kernelspec", {}).get("name") == "python3"


@pytest.mark.parametrize("name", sorted(CASES))
def test_uses_only_the_public_api(name):
    source = "\n".join(c.source for c in _read(name).cells if c.cell_type == "code")
    assert "_src" not in source, f"{name} reaches into jaxdepth._src"
    imports = set(re.findall(r"^\s*(?:import|from)\s+(jaxdepth[\w.]*)", source, flags=re.M))
    assert imports and imports <= {"jaxdepth", "jaxdepth.io", "jaxdepth.research.ablation", "jaxdepth.research.evaluation"}, imports
    assert "jax.config.update" not in source


@pytest.fixture(scope="module")
def kernel_dir(tmp_path_factory):
    """A kernelspec that starts ipykernel with this interpreter."""
    root = tmp_path_factory.mktemp("jupyter")
    spec = root / "kernels" / KERNEL
    spec.mkdir(parents=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "jaxdepth tests", "language": "python"}))
    return root


@pytest.mark.shared_data
@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(CASES))
def test_notebook_runs(name, kernel_dir, monkeypatch):
    data = require_shared(*CASES[name])
    shared = data.parents[len(CASES[name]) - 1]          # the shared/data folder itself
    monkeypatch.setenv("JUPYTER_PATH", os.pathsep.join(filter(None, [str(kernel_dir),
                                                                      os.environ.get("JUPYTER_PATH")])))
    env = dict(os.environ, JAXDEPTH_SHARED_DATA=str(shared), PYDEVD_DISABLE_FILE_VALIDATION="1")
    env.pop("MPLBACKEND", None)  # the kernel's inline backend renders the figures
    nb = _read(name)
    client = nbclient.NotebookClient(nb, kernel_name=KERNEL, timeout=600,
                                     resources={"metadata": {"path": str(NOTEBOOKS)}})
    client.execute(env=env)          # raises CellExecutionError with the cell's traceback on any error

    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    figures = sum("image/png" in o.get("data", {}) for o in outputs)
    assert figures >= MIN_FIGURES[name], f"{name}: {figures} figures drawn, expected {MIN_FIGURES[name]}"
    assert _read(name).cells[0].source == nb.cells[0].source  # the stored file was not touched
    for cell in _read(name).cells:
        assert cell.get("outputs", []) == []
