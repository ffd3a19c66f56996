"""Freeing a finished diagram: the reference cycles pydrake cannot collect, broken by hand.

Two kinds of references run through C++, where Python's garbage collector cannot see them:

* a Python ``LeafSystem`` added to a ``DiagramBuilder`` is owned by C++, and pydrake's
  ``ref_cycle`` links (the ``_pydrake_internal_ref_cycle_peers`` set that ports, builders and
  diagrams put into a system's ``__dict__``) close a loop from it back to its diagram;
* a system's C++ events and output ports hold the bound methods given as their callbacks, so
  a Python system keeps itself alive through its own C++ part.

So every diagram built in a process stayed alive with all its systems' data (drive-log buffers,
rendered textures, solver workspaces): a worker that runs one simulation after another
(``pcvfe evaluate``) grew by ~30 MB per one-lap run.

:func:`release_diagram`, called once the caller is done with a diagram, empties the peer sets
of every system (recursively), which frees the diagrams, and then the instance dictionary of
every Python leaf system, which frees what they hold; only the empty system objects (a few
hundred bytes each) stay. ``tests/diagrams/test_release.py`` checks it after a run.
"""

from __future__ import annotations

from pydrake.systems.framework import Diagram, LeafSystem, System

REF_CYCLE_PEERS = "_pydrake_internal_ref_cycle_peers"
"""pydrake's attribute holding a Python object's ref-cycle peers (``pydrake.common.ref_cycle``)."""


def all_systems(diagram: System):
    """``diagram`` and every system inside it, nested diagrams and their systems included."""
    stack = [diagram]
    while stack:
        system = stack.pop()
        yield system
        if isinstance(system, Diagram):
            stack.extend(system.GetSystems())


def release_diagram(diagram: System) -> int:
    """Free ``diagram`` and what its Python systems hold (see the module docstring); returns
    the number of Python leaf systems emptied. Neither the diagram nor any of its systems or
    ports may be used afterwards: drop every reference to them."""
    leaves = []
    for system in all_systems(diagram):
        peers = getattr(system, "__dict__", {}).get(REF_CYCLE_PEERS)
        if peers:
            peers.clear()
        if isinstance(system, LeafSystem) and hasattr(system, "__dict__"):
            leaves.append(system)
    for system in leaves:
        system.__dict__.clear()
    return len(leaves)
