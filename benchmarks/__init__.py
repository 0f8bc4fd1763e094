"""jaxdepth's benchmarks: speed and accuracy tools (see README.md here), run from the repository root
as ``python -m benchmarks.<tool>``; one-off studies in :mod:`benchmarks.studies`."""
