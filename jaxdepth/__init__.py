"""jaxdepth: non-learning LiDAR depth completion (Surface Geometry Model) in JAX."""

__version__ = "0.1.0"
