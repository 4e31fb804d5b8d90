"""Least sealing strap force: the question the seed could not answer (Heinze ch. 1, ch. 6).

The best mask seals with the least strap force. Sealing is a yes/no property of a fit
(:attr:`FitResult.sealed`: contact pressure above the therapy pressure closes a loop around the
airway), assumed monotone in the force (a mask that seals at F seals at every larger F). The search:

1. **Bracket**: fit at ``start`` N; if it seals, halve the force until it leaks (or ``minimum`` is
   reached: then the answer is "seals already at ``minimum``"); if it leaks, double it until it seals
   (or ``maximum`` is passed: then the mask does not seal on this face up to ``maximum``).
2. **Bisect** the bracket [leaks at F_lo, seals at F_hi] until ``F_hi - F_lo <= max(abs_tol,
   rel_tol x F_hi)``. The answer is F_hi (a force that seals, at most the tolerance above the least
   one); the pressure map at F_hi is reported.

A fit that does not converge while bracketing upwards is retried halfway between the largest leaking
force and the failed one (the seal may lie below the force where the model fails), until that
interval is within the tolerance; otherwise a fit that does not converge (after the first) ends the
search with status "solve-failed" and the bracket found so far, reported as such. Every fit is warm-started from the converged fit of the nearest force already solved
(:class:`headsim.mask.fit.FitState`); a failed warm start falls back to a cold one. Every solved force
also gives a point of the force -> contact area and force -> peak pressure curves.

**Least force with an acceptable leak** (beside the strict answer, which stays as it is): every fit
carries a leak-flow estimate (:mod:`headsim.mask.leak`) and the judgement "leak <= threshold"
(:attr:`FitResult.leak_acceptable`), assumed monotone in the force like the seal. After the strict
search, the solved forces are reused: the smallest acceptable one and the largest unacceptable
one below it form the bracket -- the smallest force from which every solved force is acceptable,
so an isolated acceptable fit below an unacceptable one does not count -- halving down from it, to
``minimum``, when no solved force below it is unacceptable, bisected to the same tolerance, with at
most ``max_solves`` further fits.

**Acceptable-leak window** (status "window"): the leak is not always monotone in the force. With
the consistent barrier contact the demo's leak *rises* with the force (:mod:`headsim.mask.fit`,
"Barrier contact": 3.5 L/min at 5 N, 53 L/min at 30 N, through the corners beside the nasal
bridge), so the strap can be too loose *and* too tight. When the largest solved force is
unacceptable but a smaller one is not, the answer is the window of the lowest run of acceptable
solved forces: its lower end refined as above (bisected against the unacceptable force below it,
or halved down to ``minimum``), its upper end bisected against the first unacceptable force above
it, both to the same tolerance and within the same ``max_solves`` further fits
(``leak_force`` .. ``leak_upper_force``; ``leak_upper_bound`` the least force found above the
window with too much leak). Where the fit budget runs out the status says so and the window is
the bracket reached.
A sealed fit leaks 0, so the answer is at most the strict seal force. When no solved force is
acceptable the answer is None ("leak above the threshold up to the largest force solved"); no fit
above the strict search's range is tried. Cost on the demo (nonlinear, 10-30 N, 1 N): see
:mod:`headsim.mask.fit` "Leak flow".
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from headsim.errors import ConvergenceError, ParameterError
from headsim.mask.fit import MAX_STRAP_FORCE, FitProblem, FitResult, check_force, problem_fit


@dataclass(frozen=True)
class SearchOptions:
    """Options of :func:`least_seal_force` (forces in N).

    start : first force tried; minimum, maximum : the search range (0 < minimum < maximum <= 200 N)
    abs_tol : N and rel_tol : fraction -- stop when the bracket is narrower than max(abs_tol, rel_tol F)
    max_solves : fits before giving up with the current bracket
    """

    start: float = 10.0
    minimum: float = 1.0
    maximum: float = 60.0
    abs_tol: float = 0.5
    rel_tol: float = 0.05
    max_solves: int = 14

    def __post_init__(self):
        for name in ("start", "minimum", "maximum"):
            check_force(getattr(self, name))
        if not self.minimum <= self.start <= self.maximum or self.minimum >= self.maximum:
            raise ParameterError(f"need minimum <= start <= maximum (and minimum < maximum), got "
                                 f"{self.minimum}, {self.start}, {self.maximum} N")
        if not (self.abs_tol > 0 and 0 <= self.rel_tol < 1):
            raise ParameterError("abs_tol must be > 0 N and rel_tol in [0, 1)")
        if self.max_solves < 2:
            raise ParameterError("max_solves must be >= 2")


@dataclass(frozen=True, eq=False)
class CurvePoint:
    """One solved force: N, cm^2, kPa, kPa, cm^2, bool, s, L/min, bool."""

    force: float
    contact_area_cm2: float
    peak_pressure_kpa: float
    mean_pressure_kpa: float
    area_above_threshold_cm2: float
    sealed: bool
    seconds: float
    leak_flow_lpm: float | None = None
    leak_acceptable: bool | None = None

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass(frozen=True, eq=False)
class SearchResult:
    """Outcome of :func:`least_seal_force`.

    seal_force : N, the least sealing force found (within the tolerance above the true one), or None
        when the mask does not seal up to ``options.maximum`` N
    lower_bound : N, the largest force found not to seal (None when it seals at ``minimum``)
    tolerance : N, the bracket width reached (F_hi - F_lo)
    fit : FitResult at ``seal_force`` (or at the largest force tried when it never seals)
    curve : CurvePoints sorted by force
    n_solves : fits done; seconds : wall time
    status : "sealed", "seals-at-minimum", "no-seal", "max-solves" (bracket not narrowed enough) or
        "solve-failed" (fits after the first did not converge and no seal was found below them; the
        search stops with the bracket so far)
    failures : messages of the fits that did not converge
    leak_force : N, the least force whose leak is acceptable (module doc), or None
    leak_lower_bound : N, the largest force found with an unacceptable leak (None if none below)
    leak_status : "acceptable", "acceptable-at-minimum", "not-acceptable", "window" (acceptable at some
        solved force but not at the largest: acceptable from leak_force up to leak_upper_force, module
        doc), "max-solves", "solve-failed"
    leak_solves : fits added for the leak answer (beyond the strict search's)
    leak_fit : FitResult at ``leak_force`` (None when there is none)
    leak_upper_force : N, the largest force found with an acceptable leak when the leak turns
        unacceptable again above it (the window's top; None when the leak stays acceptable up to the
        largest force solved)
    leak_upper_bound : N, the least force found above ``leak_upper_force`` with too much leak (None
        when there is no window)
    """

    seal_force: float | None
    lower_bound: float | None
    tolerance: float | None
    fit: FitResult
    curve: list[CurvePoint]
    n_solves: int
    seconds: float
    status: str
    options: SearchOptions = field(default_factory=SearchOptions)
    failures: list = field(default_factory=list)
    leak_force: float | None = None
    leak_lower_bound: float | None = None
    leak_status: str | None = None
    leak_solves: int = 0
    leak_fit: FitResult | None = None
    leak_upper_force: float | None = None
    leak_upper_bound: float | None = None

    def leak_window_text(self) -> str | None:
        """The window's top in words ("18.75 N: too much leak again from 19.38 N ..."), None without one."""
        if self.leak_upper_force is None:
            return None
        return (f"{self.leak_upper_force:.2f} N: too much leak again from {self.leak_upper_bound:.2f} N (the leak "
                f"rises with the strap force; status {self.leak_status})")

    def as_dict(self) -> dict:
        leak = getattr(self.fit, "leak", None)
        return {
            "least_seal_force_n": self.seal_force,
            "least_acceptable_leak_force_n": self.leak_force,
            "largest_unacceptable_leak_force_n": self.leak_lower_bound,
            "acceptable_leak_up_to_n": self.leak_upper_force,
            "unacceptable_leak_again_from_n": self.leak_upper_bound,
            "leak_search_status": self.leak_status,
            "leak_extra_solves": self.leak_solves,
            "leak_threshold_lpm": None if leak is None else leak.threshold_lpm,
            "largest_leaking_force_n": self.lower_bound,
            "bracket_width_n": self.tolerance,
            "status": self.status,
            "failed_fits": list(self.failures),
            "n_solves": self.n_solves,
            "search_seconds": self.seconds,
            "tolerance": {"abs_n": self.options.abs_tol, "rel": self.options.rel_tol},
            "range_n": [self.options.minimum, self.options.maximum],
            "curve": [p.as_dict() for p in self.curve],
        }


def least_seal_force(problem: FitProblem, options: SearchOptions = SearchOptions(),
                     progress: Callable[[int, int, str], None] | None = None, mode: str = "nonlinear") -> SearchResult:
    """Search the least strap force that seals (module doc).

    problem : from :func:`headsim.mask.fit.prepare_fit`
    progress : called as progress(solves_done, max_solves, message) after each fit (and, in the
        nonlinear mode, before every Newton iteration of the fit in progress)
    mode : "nonlinear" (every fit by :func:`headsim.mask.fit.problem_fit`) or "condensed" (the linear
        condensed model of :mod:`headsim.mask.condensed`, condensed once at the start; its time counts)
    """
    if options.maximum > MAX_STRAP_FORCE:
        raise ParameterError(f"maximum force must be <= {MAX_STRAP_FORCE:g} N")
    if mode not in ("nonlinear", "condensed"):
        raise ParameterError(f"mode must be 'nonlinear' or 'condensed', got {mode!r}")
    t0 = time.perf_counter()
    fits: dict[float, FitResult] = {}
    fitter = problem_fit
    if mode == "condensed":
        from headsim.mask.condensed import condense_fit, condensed_fit

        condensed = condense_fit(problem)

        def fitter(_problem, f, warm_start=None):
            return condensed_fit(condensed, f)

    failed: list[str] = []

    def solve(f: float) -> FitResult | None:
        warm = None
        if fits:
            near = min(fits, key=lambda g: abs(g - f))
            warm = fits[near].state
        extra = {}
        if progress is not None and mode == "nonlinear":
            def newton_progress(it, gnorm, tol):
                progress(len(fits), options.max_solves,
                         f"{f:.2f} N: Newton iteration {it}, force residual {gnorm:.1e} N")

            extra["progress"] = newton_progress
        try:
            r = fitter(problem, f, warm_start=warm, **extra)
        except ConvergenceError as e:
            if not fits:
                raise
            failed.append(f"{f:.2f} N: {e}")
            return None
        fits[f] = r
        if progress is not None:
            progress(len(fits), options.max_solves,
                     f"{f:.2f} N: {'sealed' if r.sealed else 'leaks'}, peak {r.summary.peak_pressure / 1e3:.1f} kPa"
                     + ("" if r.leak_flow_lpm is None else f", leak {r.leak_flow_lpm:.2f} L/min"))
        return r

    lo = hi = None
    f = options.start
    r = solve(f)
    status = "sealed"
    if r.sealed:
        lo, hi, stop = _halve_down(solve, lambda r: r.sealed, f, options, lambda: len(fits) < options.max_solves)
        status = {"at-minimum": "seals-at-minimum", "solve-failed": "solve-failed"}.get(stop, status)
    else:
        lo = f
        ceiling = None        # smallest force whose solve failed while bracketing upwards
        while len(fits) + len(failed) < options.max_solves:
            if f >= options.maximum:
                status = "no-seal"
                break
            nxt = min(2.0 * f, options.maximum) if ceiling is None else 0.5 * (lo + ceiling)
            r = solve(nxt)
            if r is None:
                # the solve fails at nxt: look for the seal below it (module doc, step 1)
                ceiling = nxt
                if ceiling - lo <= max(options.abs_tol, options.rel_tol * ceiling):
                    status = "solve-failed"
                    break
                continue
            f = nxt
            if r.sealed:
                hi = f
                break
            lo = f
            if ceiling is not None and ceiling - lo <= max(options.abs_tol, options.rel_tol * ceiling):
                status = "solve-failed"
                break
        else:
            if hi is None:
                status = "no-seal" if f >= options.maximum else "max-solves"
    if hi is not None and lo is not None and status == "sealed":
        lo, hi, stop = _bisect(solve, lambda r: r.sealed, lo, hi, options, lambda: len(fits) < options.max_solves)
        status = stop or status
    n_strict = len(fits) + len(failed)
    leak_hi, leak_lo, leak_status, leak_top, leak_over = _leak_bracket(
        solve, fits, options, lambda: len(fits) + len(failed) - n_strict < options.max_solves)
    curve = [CurvePoint(f, r.summary.contact_area_cm2, r.summary.peak_pressure / 1e3,
                        r.summary.mean_pressure / 1e3, r.summary.area_above_threshold_cm2, r.sealed, r.seconds,
                        r.leak_flow_lpm, r.leak_acceptable)
             for f, r in sorted(fits.items())]
    n = len(fits) + len(failed)
    leak = dict(leak_force=leak_hi, leak_lower_bound=leak_lo, leak_status=leak_status, leak_solves=n - n_strict,
                leak_fit=None if leak_hi is None else fits[leak_hi], leak_upper_force=leak_top,
                leak_upper_bound=leak_over)
    if hi is None:
        best = fits[max(fits)]
        return SearchResult(None, lo, None, best, curve, n, time.perf_counter() - t0,
                            status if status != "sealed" else "no-seal", options, failed, **leak)
    width = None if lo is None else hi - lo
    return SearchResult(hi, lo, width, fits[hi], curve, n, time.perf_counter() - t0, status, options, failed, **leak)


def _halve_down(solve, accept, hi: float, options: SearchOptions, budget_left):
    """From an accepted force ``hi``, halve (down to ``minimum``) until a force is rejected:
    (rejected force or None, smallest accepted force, None or "at-minimum" | "max-solves" | "solve-failed")."""
    while True:
        if hi <= options.minimum:  # checked before the budget: an accepted fit at the minimum says so
            return None, hi, "at-minimum"
        if not budget_left():
            return None, hi, "max-solves"
        f = max(hi / 2.0, options.minimum)
        r = solve(f)
        if r is None:
            return None, hi, "solve-failed"
        if not accept(r):
            return f, hi, None
        hi = f


def _bisect(solve, accept, lo: float, hi: float, options: SearchOptions, budget_left):
    """Bisect [lo rejected, hi accepted] to max(abs_tol, rel_tol hi): (lo, hi, None) or, stopped early,
    (lo, hi, "max-solves" | "solve-failed")."""
    while hi - lo > max(options.abs_tol, options.rel_tol * hi):
        if not budget_left():
            return lo, hi, "max-solves"
        mid = 0.5 * (lo + hi)
        r = solve(mid)
        if r is None:
            return lo, hi, "solve-failed"
        if accept(r):
            hi = mid
        else:
            lo = mid
    return lo, hi, None


def _leak_bracket(solve, fits: dict, options: SearchOptions, budget_left):
    """Least force with an acceptable leak from the solved ``fits``, refined (module doc): (force or
    None, largest unacceptable force below it or None, status, the window's top or None, the least
    unacceptable force above the window or None)."""
    def accept(r):
        return bool(r.leak_acceptable)

    forces = sorted(fits)
    ok = [accept(fits[f]) for f in forces]
    if not any(ok):
        return None, forces[-1], "not-acceptable", None, None
    top = over = None
    if ok[-1]:
        # the smallest force from which every solved force is acceptable
        k = len(ok) - 1
        while k > 0 and ok[k - 1]:
            k -= 1
    else:
        # acceptable somewhere but not at the largest force solved: the window of the lowest acceptable run
        k = ok.index(True)
        j = k
        while ok[j + 1]:
            j += 1
        top, over = forces[j], forces[j + 1]
    hi = forces[k]
    lo = forces[k - 1] if k else None
    stop = None
    if lo is None:
        lo, hi, stop = _halve_down(solve, accept, hi, options, budget_left)
        stop = {"at-minimum": "acceptable-at-minimum"}.get(stop, stop)
    if lo is not None:
        lo, hi, stop = _bisect(solve, accept, lo, hi, options, budget_left)
    if top is not None and stop in (None, "acceptable-at-minimum"):
        # the window's top: [top acceptable, over unacceptable], bisected with "too much leak" as the accepted side
        top, over, up_stop = _bisect(solve, lambda r: not accept(r), top, over, options, budget_left)
        stop = up_stop or "window"
    return hi, lo, stop or "acceptable", top, over
