"""LeafSystems of pcvfe-drake, one per file (installed as ``pcvfe_drake.systems``)."""
