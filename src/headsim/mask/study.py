"""Population study: the least sealing force of every face x mask, on Dask, resumable.

Each case (one face file, one built-in mask) runs :func:`headsim.mask.search.least_seal_force` in a
Dask worker (a :class:`distributed.LocalCluster` by default, or an existing scheduler by address).
The client stores every finished case **as it completes** in an SQLite database
``OUT/cases.sqlite`` (one committed row per case, successes and failures alike), so a study that is
interrupted or crashes keeps every finished case and, run again with the same output folder,
computes only the missing ones. At the end ``OUT/ranking.csv`` and ``OUT/ranking.html`` rank the
masks per face: sealing masks first, by least sealing force, then the others (written atomically);
beside the strict answer each row has the least force whose leak-flow estimate is acceptable
(:mod:`headsim.mask.leak`; ``least_acceptable_leak_force_n``) and, where the leak turns
unacceptable again at higher force, the top of that window (``acceptable_leak_up_to_n``,
:mod:`headsim.mask.search`).
"""

from __future__ import annotations

import csv
import html
import json
import os
import sqlite3
import tempfile
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Sequence

from headsim.errors import HeadsimError, ParameterError

FACE_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".vtk", ".vtu")


@dataclass(frozen=True)
class StudyOptions:
    """Per-case settings (forces N, lengths m).

    units : length unit of the face files; start, maximum, abs_tol, rel_tol, max_solves : the
    search (:class:`headsim.mask.search.SearchOptions`); tissue_layers, crop_margin : the tissue
    model (:class:`headsim.mask.fit.FitOptions`); mask_edge : element size of the built-in masks;
    mode : "nonlinear" or "condensed" (:func:`headsim.mask.search.least_seal_force`);
    friction : skin-cushion Coulomb coefficient of the nonlinear fit (FitOptions.friction);
    contact : "barrier" (default) or "planes", the nonlinear fit's contact model (FitOptions.contact)
    rotate : the mask pitches and yaws on its strap (True) or keeps its orientation (FitOptions.rotate)
    """

    units: str = "m"
    start: float = 10.0
    maximum: float = 60.0
    abs_tol: float = 1.0
    rel_tol: float = 0.05
    max_solves: int = 12
    tissue_layers: int = 1
    crop_margin: float = 0.008
    mask_edge: float = 4e-3
    mode: str = "nonlinear"
    friction: float = 0.0  # frictionless, as FitOptions
    contact: str = "barrier"
    rotate: bool = True


_SCHEMA = """CREATE TABLE IF NOT EXISTS cases (
    face TEXT NOT NULL, mask TEXT NOT NULL, status TEXT NOT NULL, sealed INTEGER,
    least_seal_force_n REAL, peak_pressure_kpa REAL, mean_pressure_kpa REAL, contact_area_cm2 REAL,
    n_solves INTEGER, seconds REAL, error TEXT, result_json TEXT, finished_at REAL,
    least_acceptable_leak_force_n REAL, acceptable_leak_up_to_n REAL,
    PRIMARY KEY (face, mask))"""
#: columns added after the first schema: (name, SQL type), added to an older store when it is opened
_ADDED_COLUMNS = (("least_acceptable_leak_force_n", "REAL"), ("acceptable_leak_up_to_n", "REAL"))
#: the study settings the stored cases were computed with (StudyOptions field -> JSON value)
_SETTINGS_SCHEMA = "CREATE TABLE IF NOT EXISTS settings (key TEXT PRIMARY KEY, value TEXT NOT NULL)"


class CaseStore:
    """SQLite store of finished cases (``path``); every :meth:`put` is committed at once."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._db = sqlite3.connect(str(self.path))
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute(_SCHEMA)
        have = {r[1] for r in self._db.execute("PRAGMA table_info(cases)")}
        for name, kind in _ADDED_COLUMNS:
            if name not in have:
                self._db.execute(f"ALTER TABLE cases ADD COLUMN {name} {kind}")
        self._db.execute(_SETTINGS_SCHEMA)
        self._db.commit()

    def check_settings(self, options: "StudyOptions") -> None:
        """Record ``options`` in a new store; in a store that holds cases, refuse (ParameterError)
        options other than those its cases were computed with, so that a resumed study never mixes
        answers of two models (e.g. ``--contact planes`` and ``barrier``). A setting the store does
        not record (a store from before it existed) must be at its default."""
        stored = dict(self._db.execute("SELECT key, value FROM settings"))
        wanted = {k: json.dumps(v) for k, v in asdict(options).items()}
        if stored or self.done():
            # a store from before the settings were recorded was computed with the defaults of its time:
            # today's, except the contact (planes until the barrier became the default)
            default = {k: json.dumps(v) for k, v in asdict(StudyOptions(contact="planes")).items()}
            differ = sorted(k for k in wanted if stored.get(k, default[k]) != wanted[k])
            if differ:
                was = ", ".join(f"{k}={json.loads(stored.get(k, default[k]))!r}" for k in differ)
                now = ", ".join(f"{k}={json.loads(wanted[k])!r}" for k in differ)
                raise ParameterError(f"{self.path} holds cases computed with {was}; this study asks for {now}: "
                                     "use another output folder, or the same settings to resume")
        self._db.executemany("INSERT OR REPLACE INTO settings (key, value) VALUES (?, ?)", wanted.items())
        self._db.commit()

    def done(self) -> set[tuple[str, str]]:
        return {(f, m) for f, m in self._db.execute("SELECT face, mask FROM cases")}

    def put(self, row: dict) -> None:
        cols = ("face", "mask", "status", "sealed", "least_seal_force_n", "peak_pressure_kpa", "mean_pressure_kpa",
                "contact_area_cm2", "n_solves", "seconds", "error", "result_json", "least_acceptable_leak_force_n",
                "acceptable_leak_up_to_n")
        vals = [row.get(c) for c in cols] + [time.time()]
        self._db.execute(f"INSERT OR REPLACE INTO cases ({', '.join(cols)}, finished_at) VALUES "
                         f"({', '.join('?' * (len(cols) + 1))})", vals)
        self._db.commit()

    def rows(self) -> list[dict]:
        cur = self._db.execute("SELECT * FROM cases ORDER BY face, mask")
        names = [d[0] for d in cur.description]
        return [dict(zip(names, r)) for r in cur.fetchall()]

    def close(self) -> None:
        self._db.close()


def run_case(face_file: str, mask_name: str, options: dict) -> dict:
    """One case (runs in a Dask worker): least seal force of ``mask_name`` on the face in ``face_file``.

    Returns a row for :class:`CaseStore`; a HeadsimError (bad face, mask that cannot be placed, a
    solve that does not converge) becomes a row with status "failed" and the message.
    """
    from headsim.mask import make_mask
    from headsim.mask.fit import FitOptions, prepare_fit
    from headsim.mask.search import SearchOptions, least_seal_force
    from headsim.mesh.io import load_surface

    o = StudyOptions(**options)
    t0 = time.perf_counter()
    row = {"face": Path(face_file).stem, "mask": mask_name}
    try:
        face = load_surface(face_file, units=o.units)
        problem = prepare_fit(face, make_mask(mask_name, edge_length=o.mask_edge),
                              FitOptions(tissue_layers=o.tissue_layers, crop_margin=o.crop_margin,
                                         friction=o.friction, contact=o.contact, rotate=o.rotate))
        res = least_seal_force(problem, SearchOptions(start=o.start, maximum=o.maximum, abs_tol=o.abs_tol,
                                                      rel_tol=o.rel_tol, max_solves=o.max_solves),
                               mode=o.mode)
    except HeadsimError as e:
        row.update(status="failed", error=f"{type(e).__name__}: {e}", seconds=time.perf_counter() - t0)
        return row
    s = res.fit.summary
    row.update(status=res.status, sealed=int(res.seal_force is not None), least_seal_force_n=res.seal_force,
               least_acceptable_leak_force_n=res.leak_force, acceptable_leak_up_to_n=res.leak_upper_force,
               peak_pressure_kpa=s.peak_pressure / 1e3, mean_pressure_kpa=s.mean_pressure / 1e3,
               contact_area_cm2=s.contact_area_cm2, n_solves=res.n_solves, seconds=time.perf_counter() - t0,
               result_json=json.dumps({"search": res.as_dict(), "fit": res.fit.as_dict()}, default=float))
    return row


def _atomic_write(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.tmp-", suffix=path.suffix, dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


RANK_COLUMNS = ("face", "rank", "mask", "sealed", "least_seal_force_n", "least_acceptable_leak_force_n",
                "acceptable_leak_up_to_n", "peak_pressure_kpa", "mean_pressure_kpa",
                "contact_area_cm2", "n_solves", "status", "error")


def ranking(rows: Sequence[dict]) -> list[dict]:
    """Rows ranked per face: sealing masks by least seal force, then the rest (by peak pressure)."""
    out = []
    by_face: dict[str, list[dict]] = {}
    for r in rows:
        by_face.setdefault(r["face"], []).append(r)
    for face in sorted(by_face):
        def key(r):
            sealed = bool(r.get("sealed"))
            return (0 if sealed else 1 if r["status"] != "failed" else 2,
                    r.get("least_seal_force_n") or 0.0, r.get("peak_pressure_kpa") or 0.0, r["mask"])
        for i, r in enumerate(sorted(by_face[face], key=key), start=1):
            out.append({c: r.get(c) for c in RANK_COLUMNS} | {"rank": i, "sealed": bool(r.get("sealed"))})
    return out


def write_ranking(out: Path, rows: Sequence[dict]) -> tuple[Path, Path]:
    """OUT/ranking.csv and OUT/ranking.html (atomic)."""
    ranked = ranking(rows)
    import io

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=RANK_COLUMNS)
    w.writeheader()
    for r in ranked:
        w.writerow(r)
    _atomic_write(out / "ranking.csv", buf.getvalue())

    def fmt(v):
        if v is None:
            return "-"
        if isinstance(v, float):
            return f"{v:.2f}"
        return str(v)

    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'><title>headsim mask study</title><style>"
             "body{font-family:system-ui,sans-serif;margin:1.5em}table{border-collapse:collapse;margin-bottom:1.5em}"
             "td,th{border:1px solid #ccc;padding:.25em .6em}th{background:#f3f3f3}</style></head><body>"
             "<h1>Mask study: least sealing strap force per face</h1>"]
    faces = sorted({r["face"] for r in ranked})
    for face in faces:
        parts.append(f"<h2>{html.escape(face)}</h2><table><tr>"
                     + "".join(f"<th>{html.escape(c)}</th>" for c in RANK_COLUMNS if c != "face") + "</tr>")
        for r in (r for r in ranked if r["face"] == face):
            parts.append("<tr>" + "".join(f"<td>{html.escape(fmt(r[c]))}</td>" for c in RANK_COLUMNS if c != "face")
                         + "</tr>")
        parts.append("</table>")
    parts.append("</body></html>")
    _atomic_write(out / "ranking.html", "".join(parts))
    return out / "ranking.csv", out / "ranking.html"


def face_files(faces_dir: str | os.PathLike) -> list[Path]:
    d = Path(faces_dir)
    if not d.is_dir():
        raise ParameterError(f"--faces must be a folder of face meshes, got {d}")
    files = sorted(p for p in d.iterdir() if p.suffix.lower() in FACE_SUFFIXES)
    if not files:
        raise ParameterError(f"{d}: no face meshes ({', '.join(FACE_SUFFIXES)})")
    stems = [p.stem for p in files]
    if len(set(stems)) != len(stems):
        raise ParameterError(f"{d}: two face files share a name stem; cases are keyed by it")
    return files


def run_study(faces_dir: str | os.PathLike, masks: Sequence[str], out: str | os.PathLike, *,
              options: StudyOptions = StudyOptions(), scheduler: str | None = None, n_workers: int = 2,
              processes: bool = True, progress: bool = False, case_fn: Callable = run_case,
              max_new_cases: int | None = None) -> dict:
    """Run every face x mask not yet in ``OUT/cases.sqlite`` on Dask; write the ranking (module doc).

    faces_dir : folder of face meshes; masks : built-in mask names; out : output folder
    scheduler : address of a running Dask scheduler (None: start a LocalCluster of ``n_workers``
        single-threaded workers, ``processes`` or threads)
    case_fn : the case function (face_file, mask, options dict) -> row (default :func:`run_case`)
    max_new_cases : stop after this many newly finished cases (a budget; run again to continue)

    Returns a summary dict: n_cases, n_computed, n_reused, n_failed, ranking paths.
    """
    from headsim.mask import mask_catalogue

    files = face_files(faces_dir)
    masks = list(masks)
    if not masks:
        raise ParameterError("no masks given")
    unknown = [m for m in masks if m not in mask_catalogue()]
    if unknown:
        raise ParameterError(f"unknown masks {unknown}; built-in masks: {', '.join(mask_catalogue())}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    store = CaseStore(out / "cases.sqlite")
    try:
        store.check_settings(options)
    except ParameterError:
        store.close()
        raise
    done = store.done()
    todo = [(f, m) for f in files for m in masks if (f.stem, m) not in done]
    n_total = len(files) * len(masks)
    computed = 0
    try:
        if todo and (max_new_cases is None or max_new_cases > 0):
            from distributed import Client, LocalCluster, as_completed

            cluster = None
            if scheduler is None:
                cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=processes,
                                       dashboard_address=None)
                client = Client(cluster)
            else:
                client = Client(scheduler)
            bar = None
            try:
                opts = asdict(options)
                futures = [client.submit(case_fn, str(f), m, opts, key=f"mask-case-{f.stem}-{m}-{time.time_ns()}",
                                         pure=False) for f, m in todo]
                if progress:
                    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

                    bar = Progress(TextColumn("study"), BarColumn(), TextColumn("{task.completed}/{task.total} cases"),
                                   TextColumn("{task.fields[msg]}"), TimeElapsedColumn())
                    bar.start()
                    task = bar.add_task("cases", total=len(futures), msg="")
                for fut in as_completed(futures):
                    try:
                        row = fut.result()
                    except Exception as e:  # a worker crash: record it, keep the others
                        key = todo[futures.index(fut)]
                        row = {"face": key[0].stem, "mask": key[1], "status": "failed",
                               "error": f"{type(e).__name__}: {e}\n{traceback.format_exc(limit=2)}"}
                    store.put(row)
                    computed += 1
                    if bar is not None:
                        bar.update(task, advance=1, msg=f"{row['face']} {row['mask']}: {row['status']}")
                    if max_new_cases is not None and computed >= max_new_cases:
                        for f in futures:
                            f.cancel()
                        break
            finally:
                if bar is not None:
                    bar.stop()
                client.close()
                if cluster is not None:
                    cluster.close()
        rows = store.rows()
    finally:
        store.close()
    csv_path, html_path = write_ranking(out, rows)
    return {"n_cases": n_total, "n_computed": computed, "n_reused": n_total - len(todo),
            "n_failed": sum(r["status"] == "failed" for r in rows), "n_stored": len(rows),
            "ranking_csv": str(csv_path), "ranking_html": str(html_path)}
