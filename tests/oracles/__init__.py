"""Frozen reference implementations used as test oracles (never imported by jaxdepth/).

Each module says where it was frozen from. They are verbatim copies of earlier
library code: tests check the current code against them, and benchmarks/ may
import them to time old and new side by side.
"""
