"""One-off studies behind figures in docs/studies.md, run as ``python -m benchmarks.studies.<name>``."""
