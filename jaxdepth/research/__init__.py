"""Research tools around the SGM: how well it does, and why.

Nothing here is needed to complete depth; the command line loads these modules
only for the commands that use them.

* :mod:`~jaxdepth.research.evaluation`: KITTI devkit scores of prediction folders or
  trees against ground truth, paired by frame identity (``jaxdepth eval``).
* :mod:`~jaxdepth.research.hidden`: hidden-point scores of a sweep where no dense
  ground truth exists (``jaxdepth hidden-eval``).
* :mod:`~jaxdepth.research.ablation`: the paper's Tables 1, 5 and 6 (``jaxdepth ablation``).
* :mod:`~jaxdepth.research.sparsity`: the paper's 64 / 32 / 16-beam study (``jaxdepth sparsity``).
* :mod:`~jaxdepth.research.baselines`: IP_Basic in OpenCV, the speed baseline.
* :mod:`~jaxdepth.research.cli`: the research subcommands of ``jaxdepth``.
"""
