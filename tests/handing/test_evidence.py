"""Exploration evidence is judged relative to the level tried: a bend driven at a low level is
evidence although its force never reaches an absolute threshold."""

import math
from dataclasses import replace

import numpy as np
import pytest

from pcvfe_drake.estimation.probe import axle_force_per_load, evidence_force, level_bend
from pcvfe_drake.vehicle.params import ford_escort

VP = ford_escort()
CAR = replace(VP, I_z=1e-4)  # the smallest the vehicle check allows: no yaw inertia to speak of
G = 9.81


def linear_bend(peak_g: float, bend_s: float = 3.0, v_mps: float = 6.0, dt: float = 0.01):
    """A bend whose yaw rate rises and falls as a sine to ``peak_g`` of lateral acceleration,
    driven on linear tyres with the car's small-slip stiffness, by a car with no yaw inertia
    (``CAR``: both axles carry ``a_y / g``): the side slip follows ``beta_dot = g K / v
    (lr r / v - beta) - r``, so that the rear slip is ``a_y / (g K)``; the steering makes the
    front slip the same."""
    t = np.arange(0.0, bend_s + 1e-9, dt)
    k = VP.mu * np.array([VP.C_Sf, VP.C_Sr])
    r = peak_g * G / v_mps * np.sin(np.pi * t / bend_s)
    beta = np.zeros(t.size)
    for i in range(1, t.size):
        rate = G * k[1] / v_mps * (CAR.lr * r[i - 1] / v_mps - beta[i - 1]) - r[i - 1]
        beta[i] = beta[i - 1] + dt * rate
    x = np.zeros((t.size, 7))
    x[:, 3], x[:, 5], x[:, 6] = v_mps, r, beta
    rows, f_f, _ = axle_force_per_load(t, x, CAR.lf, CAR.lr, CAR.I_z / CAR.m)
    front = np.interp(t, t[rows], f_f)
    yaw = np.arctan((v_mps * np.sin(beta) + CAR.lf * r) / (v_mps * np.cos(beta)))
    x[:, 2] = front / k[0] + yaw
    return t, x, k


def test_a_low_level_bend_is_evidence_relative_to_its_level():
    # the floor stated 0.2: the planner asks for 0.64 * 0.2 = 0.128 g at the apex
    level, share = 0.2, 0.64
    t, x, k = linear_bend(share * level)
    demand = share * level
    assert evidence_force(share, level) == pytest.approx(0.5 * demand)
    relative = level_bend(t, x, CAR, k, evidence_force(share, level), demand)
    assert relative == pytest.approx(1.0, abs=0.05)  # linear tyres: the ratio is 1
    # an absolute 0.1 g leaves less than the least bend time above it: no evidence
    assert math.isnan(level_bend(t, x, CAR, k, 0.1, demand))
    # the same bend at a level four times higher: evidence too, on the same share of it
    t, x, k = linear_bend(share * 4 * level)
    assert level_bend(t, x, CAR, k, evidence_force(share, 4 * level), 4 * demand) == (
        pytest.approx(1.0, abs=0.05)
    )
