"""Searches for a minimum, pure arithmetic: the tuner's fit of an axis model is a few
hundred predictor runs steered by these (no numpy/scipy: the driver's dependencies stay
pyserial, pyftdi and click)."""

from __future__ import annotations

import math
from collections.abc import Callable


def nelder_mead(f: Callable[[list[float]], float], x0: list[float], steps: list[float],
                 iters: int) -> tuple[list[float], float]:
    """The minimum of ``f`` near ``x0`` (the Nelder-Mead simplex, ``steps`` its first
    edge along each axis, ``iters`` moves): (point, value).  No derivatives: the residual of
    a fit through the chip's integer arithmetic has none worth the name."""
    pts = [list(x0)]
    for i, s in enumerate(steps):
        p = list(x0)
        p[i] += s
        pts.append(p)
    vals = [f(p) for p in pts]
    n = len(x0)
    for _ in range(iters):
        order = sorted(range(n + 1), key=vals.__getitem__)
        pts = [pts[i] for i in order]
        vals = [vals[i] for i in order]
        cen = [sum(p[j] for p in pts[:-1]) / n for j in range(n)]
        worst = pts[-1]
        xr = [c + (c - w) for c, w in zip(cen, worst)]
        fr = f(xr)
        if fr < vals[0]:
            xe = [c + 2 * (c - w) for c, w in zip(cen, worst)]
            fe = f(xe)
            pts[-1], vals[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < vals[-2]:
            pts[-1], vals[-1] = xr, fr
        else:
            xc = [c + 0.5 * (w - c) for c, w in zip(cen, worst)]
            fc = f(xc)
            if fc < vals[-1]:
                pts[-1], vals[-1] = xc, fc
            else:
                best = pts[0]
                pts = [best] + [[b + 0.5 * (q - b) for b, q in zip(best, p)] for p in pts[1:]]
                vals = [vals[0]] + [f(p) for p in pts[1:]]
    i = min(range(n + 1), key=vals.__getitem__)
    return pts[i], vals[i]


def golden(f: Callable[[float], float], a: float, b: float, tol: float = 0.01) -> float:
    """The minimum of ``f`` on [a, b] (golden-section search, ``f`` unimodal there)."""
    r = (math.sqrt(5) - 1) / 2
    c, d = b - r * (b - a), a + r * (b - a)
    fc, fd = f(c), f(d)
    while b - a > tol:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - r * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + r * (b - a)
            fd = f(d)
    return (a + b) / 2



__all__ = ["golden", "nelder_mead"]
