"""Plain-numpy geometry of the Meshcat debugging layers (``/pcvfe/plan``, ``friction_circle``,
``camera``, ``features``); the LeafSystems in ``pcvfe_drake.systems`` only draw it."""
