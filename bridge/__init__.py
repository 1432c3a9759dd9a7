"""Where the symbolic ground truth meets the learned models: matrix-equivalence analyses,
reports, the paper's five task pipelines and the ``softpinn`` command line."""

__version__ = "0.1.0"
