"""Execute the notebooks in this folder and store them with their outputs.

    python notebooks/execute.py                       # every notebook
    python notebooks/execute.py 02_nuscenes_surround  # one (name with or without .ipynb)

Each notebook runs top to bottom in a fresh kernel started from *this* interpreter (a kernelspec written
to a temporary JUPYTER_PATH, so the kernel imports the same jaxdepth as the command), with the notebook's
folder as working folder and ``JAXDEPTH_SHARED_DATA`` taken from the environment or found as the first
``shared/data`` above the repository. Any cell error stops that notebook and leaves its stored file as it
was. The executed notebook is normalised before it is written (atomically): no per-cell timing metadata,
the kernelspec and language info reduced to the portable ``python3`` / ``python``, so executing again
changes only what the code prints (timings) and, if the data or the code changed, the figures. Figures are
stored as 8-bit palette PNGs (Pillow's median-cut palette of 256 colours, Floyd-Steinberg dithered so that
smooth depth ramps show no false contours; deterministic): about half the bytes of matplotlib's RGBA PNGs,
so a notebook with its figures stays near 1 MB; a live run in Jupyter shows the full-colour figures.

Needs the ``notebooks`` extra (``pip install -e ".[notebooks]"``).
"""

from __future__ import annotations

import argparse
import base64
import io
import json
import os
import pathlib
import sys
import tempfile
import time

import nbclient
import nbformat

HERE = pathlib.Path(__file__).resolve().parent
KERNEL = "jaxdepth-notebooks"
KERNELSPEC = {"display_name": "Python 3 (ipykernel)", "language": "python", "name": "python3"}


def shared_data() -> pathlib.Path:
    env = os.environ.get("JAXDEPTH_SHARED_DATA")
    if env:
        return pathlib.Path(env)
    for folder in HERE.parents:
        if (folder / "shared" / "data").is_dir():
            return folder / "shared" / "data"
    raise SystemExit(f"execute.py: shared/data not found above {HERE}: set JAXDEPTH_SHARED_DATA")


def write_kernelspec(root: pathlib.Path) -> None:
    spec = root / "kernels" / KERNEL
    spec.mkdir(parents=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "jaxdepth notebooks", "language": "python"}))


def normalise(nb) -> None:
    """Drops what changes from run to run but says nothing about the results."""
    nb.metadata["kernelspec"] = dict(KERNELSPEC)
    nb.metadata["language_info"] = {"name": "python"}
    nb.metadata.pop("widgets", None)
    for cell in nb.cells:
        cell.metadata.pop("execution", None)
        if cell.cell_type == "code":
            for output in cell.outputs:
                output.get("metadata", {}).pop("execution", None)
                if "image/png" in output.get("data", {}):
                    output["data"]["image/png"] = compact_png(output["data"]["image/png"])


def compact_png(data: str) -> str:
    """A base64 PNG as an 8-bit palette PNG (256 colours), base64 again."""
    from PIL import Image
    image = Image.open(io.BytesIO(base64.b64decode(data))).convert("RGB")
    palette = image.quantize(256, method=Image.Quantize.MEDIANCUT)
    image = image.quantize(palette=palette, dither=Image.Dither.FLOYDSTEINBERG)
    buffer = io.BytesIO()
    image.save(buffer, format="png", optimize=True)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def execute(path: pathlib.Path, env: dict) -> float:
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(nb, kernel_name=KERNEL, timeout=1200, record_timing=False,
                                     resources={"metadata": {"path": str(path.parent)}})
    start = time.perf_counter()
    client.execute(env=env)
    took = time.perf_counter() - start
    normalise(nb)
    nbformat.validate(nb)
    sys.path.insert(0, str(HERE.parent))
    from jaxdepth.io.atomic import atomic_write_bytes
    atomic_write_bytes(path, (nbformat.writes(nb) + "\n").encode("utf-8"))
    return took


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="notebooks to run (default: every *.ipynb here)")
    args = parser.parse_args(argv)
    paths = [HERE / (n if n.endswith(".ipynb") else n + ".ipynb") for n in args.names] or sorted(HERE.glob("*.ipynb"))
    for path in paths:
        if not path.is_file():
            raise SystemExit(f"execute.py: {path}: no such notebook")
    with tempfile.TemporaryDirectory() as jupyter:
        write_kernelspec(pathlib.Path(jupyter))
        os.environ["JUPYTER_PATH"] = os.pathsep.join(filter(None, [jupyter, os.environ.get("JUPYTER_PATH")]))
        env = dict(os.environ, JAXDEPTH_SHARED_DATA=str(shared_data()), PYDEVD_DISABLE_FILE_VALIDATION="1",
                   PYTHONPATH=os.pathsep.join(filter(None, [str(HERE.parent), os.environ.get("PYTHONPATH")])))
        env.pop("MPLBACKEND", None)  # the kernel's inline backend renders the figures
        for path in paths:
            took = execute(path, env)
            print(f"{path.name}: executed in {took:.0f} s, {path.stat().st_size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
