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
**Parallel search** (``workers`` = k > 1): the search runs in rounds of up to k forces solved at once,
each in its own worker process (SuperLU, ipctk and the Newton loop are serial, so a fit uses one core),
each warm-started from the nearest force solved *before* the round (so the rounds, and with them the
answer, do not depend on which fit finishes first). Bracketing doubles (halves) k steps ahead, a
bracket is cut into k + 1 parts instead of two, and the acceptable-leak window's two ends are refined
side by side, one fit each per round. With k = 1 every rule reduces to the one-at-a-time search
above, fit for fit. The fits of a round start from states one round older, so a fit can take longer
than its one-at-a-time counterpart (measured: 30 N from 10 N 31 s against 22 s from 20 N).
Measured on the demo problem with the barrier contact (``headsim mask seal-force --contact barrier``,
default 10-30 N, 0.5 N; 2 cores, a second job on the machine): the same answer (no seal up to 30 N,
acceptable leak from 1.00 up to 18.75 N) in 11 fits, 94.6 s one at a time, 69-75 s with two workers
(12 s first fit, 31 s for 20 and 30 N together, then four rounds of 10.5, 7.2, 4.5 and 2.7 s;
``benchmarks/bench_mask.py --fits-only``: 68.9 s at load 1.0; ``headsim demo``, 1 N tolerance: 73.0 s
search, 76.6 s wall at load 1.8). With the lagged factorisation (:mod:`headsim.mask.fit`, "Barrier
contact", ``LAGGED_NEWTON``), same answer: 70.6 -> 60.7 s in one session (first fit 12.0 -> 8.7 s,
30 N from 10 N 32.1 -> 24.2 s); ``bench_mask.py --fits-only`` 60.2 s at load 0.7, ``headsim demo``
60.9 s search, 64.4 s wall. With truncated CG on the exact Hessian and the additive CCD (same
answer): ``bench_mask.py --fits-only`` 28.8 s (cold 15 N fit 8.7 s), ``headsim demo`` 30.5 s search,
34.2 s wall. Goal 60 s: met. The
planes contact's fits depend on their warm start (lagged planes), so its parallel rounds can change
the answer: the demo's planes search gave "acceptable from 2.81 N" one at a time and a window 2.71-20 N
with two workers, in 25 s against 13 s (the worker start-up does not pay for 1-2 s fits); the CLI's
``--workers auto`` therefore uses two workers for the barrier contact only.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from concurrent.futures import Executor
from typing import Callable

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
                     progress: Callable[[int, int, str], None] | None = None, mode: str = "nonlinear",
                     workers: int = 1, executor: Executor | None = None) -> SearchResult:
    """Search the least strap force that seals (module doc).

    problem : from :func:`headsim.mask.fit.prepare_fit`
    progress : called as progress(solves_done, max_solves, message) after each fit (and, with one
        worker in the nonlinear mode, before every Newton iteration of the fit in progress)
    mode : "nonlinear" (every fit by :func:`headsim.mask.fit.problem_fit`) or "condensed" (the linear
        condensed model of :mod:`headsim.mask.condensed`, condensed once at the start; its time counts)
    workers : fits solved at once (module doc "Parallel search"): 1 solves one force after another in
        this process; k > 1 solves up to k forces of a round together in k worker processes (nonlinear
        mode only; the condensed fits take 0.1-0.2 s, so they always run here, one after another)
    executor : a :class:`concurrent.futures.Executor` to run the fits of ``workers`` > 1 instead of the
        worker processes this function starts (e.g. a thread pool for tests with a stand-in fitter)

    The worker processes are started with multiprocessing's "spawn" method (a fresh interpreter; forking
    a process whose Numba or BLAS threads have run can deadlock), which imports the calling script's
    main module again: call it from a script under ``if __name__ == "__main__":``.
    """
    if options.maximum > MAX_STRAP_FORCE:
        raise ParameterError(f"maximum force must be <= {MAX_STRAP_FORCE:g} N")
    if mode not in ("nonlinear", "condensed"):
        raise ParameterError(f"mode must be 'nonlinear' or 'condensed', got {mode!r}")
    if int(workers) != workers or workers < 1:
        raise ParameterError(f"workers must be an integer >= 1, got {workers}")
    t0 = time.perf_counter()
    if mode == "condensed":
        workers = 1
    with _FitRunner(problem, mode, int(workers), executor, progress, options.max_solves) as runner:
        search = _Search(runner, options)
        return search.run(t0)


def _fit_call(problem, force: float, warm_start):
    """One nonlinear fit (in a worker: the problem set by :func:`_worker_init` when ``problem`` is None)."""
    return problem_fit(_WORKER_PROBLEM if problem is None else problem, force, warm_start=warm_start)


_WORKER_PROBLEM = None


def _worker_init(problem_bytes: bytes, threads: int) -> None:
    """A worker process: the problem, and its share of the cores for Numba's parallel kernels."""
    import pickle

    import numba

    global _WORKER_PROBLEM
    _WORKER_PROBLEM = pickle.loads(problem_bytes)
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))


class _FitRunner:
    """Solves the forces of one round: one after another in this process, or together in workers."""

    def __init__(self, problem, mode, workers, executor, progress, max_solves):
        self.problem, self.workers, self.progress, self.max_solves = problem, workers, progress, max_solves
        self.fits: dict[float, FitResult] = {}
        self.failed: list[str] = []
        self._own_pool = None
        self.executor = executor
        if mode == "condensed":
            from headsim.mask.condensed import condense_fit, condensed_fit

            condensed = condense_fit(problem)

            def fitter(_problem, f, warm_start=None):
                return condensed_fit(condensed, f)

            self.fitter = fitter
        else:
            self.fitter = None  # problem_fit, looked up at call time
        if workers > 1 and executor is None:
            import multiprocessing
            import os
            import pickle
            from concurrent.futures import ProcessPoolExecutor

            # spawn: a clean interpreter (forking a process whose Numba / BLAS threads have run is unsafe)
            self._own_pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                                 initializer=_worker_init,
                                                 initargs=(pickle.dumps(problem), (os.cpu_count() or 1) // workers))
            self.executor = self._own_pool

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self._own_pool is not None:
            self._own_pool.shutdown(wait=True, cancel_futures=True)

    def warm_start(self, force: float):
        """The converged state of the nearest force solved so far (None before the first fit)."""
        if not self.fits:
            return None
        return self.fits[min(self.fits, key=lambda g: abs(g - force))].state

    def _record(self, f: float, r: FitResult | None, error: Exception | None) -> FitResult | None:
        if error is not None:
            if not self.fits and not self.failed:   # the search's first fit: nothing to bracket from
                raise error
            self.failed.append(f"{f:.2f} N: {error}")
            return None
        self.fits[f] = r
        if self.progress is not None:
            self.progress(len(self.fits), self.max_solves,
                          f"{f:.2f} N: {'sealed' if r.sealed else 'leaks'}, peak {r.summary.peak_pressure / 1e3:.1f} kPa"
                          + ("" if r.leak_flow_lpm is None else f", leak {r.leak_flow_lpm:.2f} L/min"))
        return r

    def solve(self, forces: list[float]) -> dict[float, FitResult | None]:
        """Fit every force (each warm-started from the nearest force solved before this round); a fit
        that does not converge gives None (the very first fit of a search raises instead)."""
        warm = {f: self.warm_start(f) for f in forces}
        out = {}
        if self.workers == 1 or len(forces) == 1:   # one force: here, with Newton progress
            for f in forces:
                out[f] = self._solve_here(f, warm[f])
            return out
        futures = {f: self.executor.submit(_fit_call, None if self._own_pool is not None else self.problem,
                                           f, warm[f]) for f in forces}
        if self.progress is not None:
            self.progress(len(self.fits), self.max_solves,
                          "fitting " + ", ".join(f"{f:.2f}" for f in forces) + f" N ({len(forces)} at once)")
        results = {}
        for f, fut in futures.items():
            try:
                results[f] = (fut.result(), None)
            except ConvergenceError as e:
                results[f] = (None, e)
        for f in forces:  # recorded in the round's order: the same fits dict whatever finished first
            out[f] = self._record(f, *results[f])
        return out

    def _solve_here(self, f, warm):
        extra = {}
        if self.progress is not None and self.fitter is None:
            def newton_progress(it, gnorm, tol):
                self.progress(len(self.fits), self.max_solves,
                              f"{f:.2f} N: Newton iteration {it}, force residual {gnorm:.1e} N")

            extra["progress"] = newton_progress
        try:
            r = (self.fitter or problem_fit)(self.problem, f, warm_start=warm, **extra)
        except ConvergenceError as e:
            return self._record(f, None, e)
        return self._record(f, r, None)


class _Search:
    """The search of the module doc, in rounds of up to ``runner.workers`` forces ("Parallel search")."""

    def __init__(self, runner: _FitRunner, options: SearchOptions):
        self.runner, self.o = runner, options

    def _narrow(self, lo: float, hi: float) -> bool:
        return hi - lo <= max(self.o.abs_tol, self.o.rel_tol * hi)

    def _drive(self, steppers: list, budget_left: Callable[[], int]) -> None:
        """Run the steppers in rounds: each active stepper (in order) gets one of the round's slots,
        the first ones the spare slots; with one worker the first active stepper runs alone until done."""
        k = self.runner.workers
        while True:
            for s in steppers:
                a = s.after
                if not s.done and not s.started and a is not None and a.done and a.result[2] not in (None, "at-minimum"):
                    s.done = True   # its predecessor stopped early: it does not start (as with one worker)
                    s.result = (s.lo, s.hi, None)
            active = [s for s in steppers if not s.done]
            if not active:
                return
            left = budget_left()
            if left <= 0:
                for s in active:
                    s.out_of_budget()
                return
            slots = min(k, left)
            share = [0] * len(active)
            for i in range(slots):
                share[i % len(active)] += 1
            plan = []
            for s, n in zip(active, share):
                if n:
                    forces = [f for f in s.propose(n) if f not in self.runner.fits]
                    plan.append((s, forces))
            forces = list(dict.fromkeys(f for _, fs in plan for f in fs))
            res = self.runner.solve(forces) if forces else {}
            for s, fs in plan:
                s.take({f: res.get(f, self.runner.fits.get(f)) for f in s.proposed})

    def run(self, t0: float) -> SearchResult:
        o, runner = self.o, self.runner
        fits, failed = runner.fits, runner.failed

        def strict_budget():
            return o.max_solves - len(fits) - len(failed)

        r = runner.solve([o.start])[o.start]
        lo = hi = None
        status = "sealed"
        if r.sealed:
            down = _HalveDown(o.start, lambda r: r.sealed, o, self._narrow)
            self._drive([down], strict_budget)
            lo, hi, stop = down.result
            if down.bisected:
                status = stop or status
            else:   # out of fits while halving: sealed at hi, no bracket below
                status = {"at-minimum": "seals-at-minimum", "solve-failed": "solve-failed"}.get(stop, status)
        else:
            up = _BracketUp(o.start, self._narrow, o)
            self._drive([up], strict_budget)
            lo, hi, status = up.result
            if hi is not None and status == "sealed":
                bis = _Bisect(lo, hi, lambda r: r.sealed, self._narrow)
                self._drive([bis], strict_budget)
                lo, hi, stop = bis.result
                status = stop or status
        n_strict = len(fits) + len(failed)
        leak = self._leak_bracket(lambda: o.max_solves - (len(fits) + len(failed) - n_strict))
        leak_hi, leak_lo, leak_status, leak_top, leak_over = leak
        curve = [CurvePoint(f, r.summary.contact_area_cm2, r.summary.peak_pressure / 1e3,
                            r.summary.mean_pressure / 1e3, r.summary.area_above_threshold_cm2, r.sealed, r.seconds,
                            r.leak_flow_lpm, r.leak_acceptable)
                 for f, r in sorted(fits.items())]
        n = len(fits) + len(failed)
        extra = dict(leak_force=leak_hi, leak_lower_bound=leak_lo, leak_status=leak_status,
                     leak_solves=n - n_strict, leak_fit=None if leak_hi is None else fits[leak_hi],
                     leak_upper_force=leak_top, leak_upper_bound=leak_over)
        if hi is None:
            best = fits[max(fits)]
            return SearchResult(None, lo, None, best, curve, n, time.perf_counter() - t0,
                                status if status != "sealed" else "no-seal", o, list(failed), **extra)
        width = None if lo is None else hi - lo
        return SearchResult(hi, lo, width, fits[hi], curve, n, time.perf_counter() - t0, status, o,
                            list(failed), **extra)

    def _leak_bracket(self, budget_left):
        """Least force with an acceptable leak from the solved fits, refined (module doc): (force or
        None, largest unacceptable force below it or None, status, the window's top or None, the least
        unacceptable force above the window or None). The window's two ends are refined side by side."""
        fits, o = self.runner.fits, self.o

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
        lower = _HalveDown(hi, accept, o, self._narrow) if lo is None else _Bisect(lo, hi, accept, self._narrow)
        steppers = [lower]
        upper = None
        if top is not None:
            # the window's top: [top acceptable, over unacceptable], bisected with "too much leak" accepted
            upper = _Bisect(top, over, lambda r: not accept(r), self._narrow, after=lower)
            steppers.append(upper)
        self._drive(steppers, budget_left)
        lo, hi, stop = lower.result
        if stop == "at-minimum":
            stop = "acceptable-at-minimum"
        if upper is not None and stop in (None, "acceptable-at-minimum"):
            top, over, up_stop = upper.result
            stop = up_stop or "window"
        elif upper is not None and upper.started:
            top, over = upper.result[:2]   # refined alongside the lower end before it stopped
        return hi, lo, stop or "acceptable", top, over


class _Stepper:
    """One bracket refined in rounds: ``propose(n)`` -> up to n forces, ``take(results)`` updates."""

    done = False
    started = False
    result = None
    after = None   # a stepper that must end well first when fits run one at a time

    def propose(self, n: int) -> list[float]:
        self.started = True
        self.proposed = self._propose(n)
        return self.proposed


class _HalveDown(_Stepper):
    """From an accepted force ``hi``, halve (down to ``minimum``) until a force is rejected, then bisect
    [rejected, accepted] to the tolerance. Result: (largest rejected force or None, smallest accepted
    force, stop) with stop None or "at-minimum" | "max-solves" | "solve-failed"; ``bisected`` tells
    whether the stop came while bisecting."""

    def __init__(self, hi, accept, options, narrow):
        self.hi, self.accept, self.minimum, self.narrow = hi, accept, options.minimum, narrow
        self.bisect = None
        self._check()

    @property
    def bisected(self) -> bool:
        return self.bisect is not None

    def _check(self):
        if self.hi <= self.minimum:  # checked before the budget: an accepted fit at the minimum says so
            self.done, self.result = True, (None, self.hi, "at-minimum")

    def out_of_budget(self):
        if self.bisect is not None:
            self.bisect.out_of_budget()
            self.done, self.result = True, self.bisect.result
            return
        self.done, self.result = True, (None, self.hi, "max-solves")

    def _propose(self, n):
        if self.bisect is not None:
            return self.bisect.propose(n)
        out, f = [], self.hi
        for _ in range(n):
            f = max(f / 2.0, self.minimum)
            out.append(f)
            if f <= self.minimum:
                break
        return out

    def take(self, results):
        if self.bisect is not None:
            self.bisect.take(results)
            self.done, self.result = self.bisect.done, self.bisect.result
            return
        for f in self.proposed:   # descending
            r = results[f]
            if r is None:
                self.done, self.result = True, (None, self.hi, "solve-failed")
                return
            if not self.accept(r):
                self.bisect = _Bisect(f, self.hi, self.accept, self.narrow)
                self.done, self.result = self.bisect.done, self.bisect.result
                return
            self.hi = f
        self._check()


class _Bisect(_Stepper):
    """Narrow [lo rejected, hi accepted] to max(abs_tol, rel_tol hi) by n-section (bisection with one
    force per round). Result: (lo, hi, None) or, stopped early, (lo, hi, "max-solves" | "solve-failed")."""

    def __init__(self, lo, hi, accept, narrow, after=None):
        self.lo, self.hi, self.accept, self.narrow, self.after = lo, hi, accept, narrow, after
        self._check()

    def _check(self):
        if self.narrow(self.lo, self.hi):
            self.done, self.result = True, (self.lo, self.hi, None)

    def out_of_budget(self):
        self.done, self.result = True, (self.lo, self.hi, "max-solves")

    def _propose(self, n):
        return [self.lo + (j + 1) * (self.hi - self.lo) / (n + 1) for j in range(n)]

    def take(self, results):
        for f in self.proposed:   # ascending
            r = results[f]
            if r is None:
                self.done, self.result = True, (self.lo, self.hi, "solve-failed")
                return
            if self.accept(r):
                self.hi = f
                break
            self.lo = f
        self._check()


class _BracketUp(_Stepper):
    """From a force ``lo`` that leaks, double (up to ``maximum``) until one seals; a fit that fails is
    a ceiling: the next forces lie between the largest leaking force and it (module doc, step 1).
    Result: (largest leaking force, sealing force or None, "sealed" | "no-seal" | "max-solves" |
    "solve-failed")."""

    def __init__(self, lo, narrow, options):
        self.lo, self.narrow, self.maximum = lo, narrow, options.maximum
        self.ceiling = None
        self._check()

    def _check(self):
        if self.lo >= self.maximum:
            self.done, self.result = True, (self.lo, None, "no-seal")

    def out_of_budget(self):
        self.done, self.result = True, (self.lo, None, "max-solves")

    def _propose(self, n):
        if self.ceiling is not None:
            return [self.lo + (j + 1) * (self.ceiling - self.lo) / (n + 1) for j in range(n)]
        out, f = [], self.lo
        for _ in range(n):
            f = min(2.0 * f, self.maximum)
            out.append(f)
            if f >= self.maximum:
                break
        return out

    def take(self, results):
        for f in self.proposed:   # ascending
            r = results[f]
            if r is None:
                self.ceiling = f
                if self.narrow(self.lo, f):
                    self.done, self.result = True, (self.lo, None, "solve-failed")
                    return
                break
            if r.sealed:
                self.done, self.result = True, (self.lo, f, "sealed")
                return
            self.lo = f
        if self.ceiling is not None and self.narrow(self.lo, self.ceiling):
            self.done, self.result = True, (self.lo, None, "solve-failed")
            return
        self._check()
