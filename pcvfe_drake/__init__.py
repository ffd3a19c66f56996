"""pcvfe_drake: PC-VFE (physics-constrained, vision-informed friction estimation) in Drake.

The core package (models, estimation, clustering, diagnostics, logs, CLI) is plain numpy/scipy and
never imports pydrake; the LeafSystems live in ``pcvfe_drake.systems`` and the diagram factories in
``pcvfe_drake.diagrams``.
"""

__version__ = "0.1.0"
