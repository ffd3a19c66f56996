"""Index bookkeeping and fixed sparsity patterns of the NMPC's QP.

:class:`QpLayout` names where each variable and constraint row of the QP lives;
:class:`SparsityPattern` holds a fixed sparsity (built once) and the permutation that writes new
values straight into CSC data, so each controller update only fills a value vector.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from pcvfe_drake.vehicle.single_track import NU, NX


class QpLayout:
    """Index bookkeeping of the QP: variables ``dz = [dx_0..dx_N, du_0..du_{N-1}, s_fric_0..
    s_fric_{N-1}, s_lat_1..s_lat_N]`` and constraint rows ``[init (7), dynamics (7N), inputs (2N),
    steering angle (N), friction (8N), corridor (2N), slack >= 0 (2N)]``."""

    N_FRICTION_SIDES = 8

    def __init__(self, horizon: int) -> None:
        n = int(horizon)
        self.N = n
        self.n_x = NX * (n + 1)
        self.n_u = NU * n
        self.off_u = self.n_x
        self.off_sf = self.n_x + self.n_u
        self.off_sl = self.off_sf + n
        self.nz = self.off_sl + n
        self.r_init = 0
        self.r_dyn = NX
        self.r_in = self.r_dyn + NX * n
        self.r_del = self.r_in + NU * n
        self.r_fr = self.r_del + n
        self.r_lat = self.r_fr + self.N_FRICTION_SIDES * n
        self.r_sl = self.r_lat + 2 * n
        self.m = self.r_sl + 2 * n
        angles = np.arange(self.N_FRICTION_SIDES) * (2 * np.pi / self.N_FRICTION_SIDES)
        self.fr_cos = np.cos(angles)
        self.fr_sin = np.sin(angles)

    def ix(self, k, i):
        return NX * np.asarray(k) + np.asarray(i)

    def iu(self, k, j):
        return self.off_u + NU * np.asarray(k) + np.asarray(j)

    def shift_rows(self) -> np.ndarray:
        """For warm starts: the row of the next stage of each row (the last stage keeps its own)."""
        n = self.N
        src = np.arange(self.m)

        def shift(first: int, per_stage: int, stages: int) -> None:
            rows = first + np.arange(stages * per_stage).reshape(stages, per_stage)
            src[rows[:-1]] = rows[1:]

        shift(self.r_dyn, NX, n)
        shift(self.r_in, NU, n)
        shift(self.r_del, 1, n)
        shift(self.r_fr, self.N_FRICTION_SIDES, n)
        shift(self.r_lat, 2, n)
        shift(self.r_sl, 1, n)
        shift(self.r_sl + n, 1, n)
        return src


class SparsityPattern:
    """Fixed sparsity: blocks of (row, col) entries in a fixed order, and the permutation from
    that order to CSC data order. ``csc(values)`` builds the matrix once; ``data(values)`` gives
    the CSC data vector of new values in the same pattern."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.shape = shape
        self._rows: list[np.ndarray] = []
        self._cols: list[np.ndarray] = []
        self.blocks: dict[str, slice] = {}
        self.size = 0

    def add(self, name: str, rows, cols) -> None:
        rows, cols = np.broadcast_arrays(np.asarray(rows), np.asarray(cols))
        self._rows.append(rows.ravel())
        self._cols.append(cols.ravel())
        self.blocks[name] = slice(self.size, self.size + rows.size)
        self.size += rows.size

    def finish(self) -> None:
        rows = np.concatenate(self._rows)
        cols = np.concatenate(self._cols)
        key = cols.astype(np.int64) * self.shape[0] + rows
        if np.unique(key).size != key.size:
            raise RuntimeError("QP pattern has duplicate entries")
        order = np.argsort(key, kind="stable")  # CSC order: by column, then row
        self.perm = order
        self.indices = rows[order].astype(np.int32)
        counts = np.bincount(cols, minlength=self.shape[1])
        self.indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)

    def data(self, values: np.ndarray) -> np.ndarray:
        return values[self.perm]

    def csc(self, values: np.ndarray) -> sp.csc_matrix:
        return sp.csc_matrix((self.data(values), self.indices, self.indptr), shape=self.shape)
