"""Soft checks: a test records every mismatch and reports them all at once, with its logs."""

from __future__ import annotations

import math

import numpy as np
import pytest


def wrap_pi(a):
    """Wrap to (−π, π]."""
    w = np.mod(np.asarray(a, float) + math.pi, 2 * math.pi) - math.pi
    return np.where(w == -math.pi, math.pi, w)


class Checks:
    """Mismatches, each with what it is; ``done`` fails the test with all of them."""

    def __init__(self):
        self.failures: list[str] = []

    def true(self, cond, what):
        if not cond:
            self.failures.append(what)
        return bool(cond)

    def equal(self, actual, expected, what):
        return self.true(actual == expected, f"{what}: expected {expected!r}, got {actual!r}")

    def close(self, actual, expected, tol, what):
        a = np.asarray(actual, float)
        e = np.asarray(expected, float)
        if a.shape != e.shape:
            return self.true(False, f"{what}: shape {a.shape} != expected {e.shape}")
        err = np.abs(a - e)
        if err.size and not np.all(err <= tol):
            i = int(np.nanargmax(np.where(np.isnan(err), np.inf, err)))
            bad = int(np.sum(~(err <= tol)))
            return self.true(
                False,
                f"{what}: {bad}/{err.size} beyond {tol:g}; worst index {i}: "
                f"got {a.flat[i]!r}, expected {e.flat[i]!r} (|err| {err.flat[i]:.3g})",
            )
        return True

    def angles_close(self, actual, expected, tol, what):
        a = np.asarray(actual, float)
        e = np.asarray(expected, float)
        if a.shape != e.shape:
            return self.true(False, f"{what}: shape {a.shape} != expected {e.shape}")
        return self.close(wrap_pi(a - e), np.zeros_like(a), tol, what + " (wrapped difference)")

    def done(self, logs: str = ""):
        if self.failures:
            text = "\n".join(f"- {f}" for f in self.failures)
            pytest.fail(f"{len(self.failures)} mismatch(es) with docs/protocol/:\n{text}\n{logs}")
