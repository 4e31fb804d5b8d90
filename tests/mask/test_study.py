"""Population study on Dask: SQLite store of finished cases, resume without recomputing, ranking."""

import csv
import shutil
import sqlite3

import pytest

from headsim.data import face_path
from headsim.errors import ParameterError
from headsim.mask.study import CaseStore, StudyOptions, ranking, run_study

# case functions run in Dask workers (threads here): module-level, deterministic
_FORCE = {"nasal-S": 12.0, "nasal-M": 9.0, "nasal-L": None}


def fake_case(face_file, mask, options):
    """Stands in for the (slow) least-seal-force search: the store, resume and ranking logic is what
    is tested here; run_case itself is the search tested in test_search.py."""
    from pathlib import Path

    face = Path(face_file).stem
    if face == "face_bad":
        return {"face": face, "mask": mask, "status": "failed", "error": "MeshError: not a face"}
    f = _FORCE[mask]
    return {"face": face, "mask": mask, "status": "sealed" if f else "no-seal", "sealed": int(f is not None),
            "least_seal_force_n": f, "peak_pressure_kpa": 30.0 + (f or 50.0), "mean_pressure_kpa": 10.0,
            "contact_area_cm2": 5.0, "n_solves": 4, "seconds": 0.0}


@pytest.fixture
def faces(tmp_path):
    d = tmp_path / "faces"
    d.mkdir()
    for name in ("neutral", "identity000"):
        shutil.copy(face_path(name), d / f"face_{name}.obj")
    (d / "face_bad.obj").write_text("v 0 0 0\n")
    return d


def _rows(out):
    with sqlite3.connect(out / "cases.sqlite") as db:
        return db.execute("SELECT face, mask, status FROM cases ORDER BY face, mask").fetchall()


def test_study_stores_every_case_and_resumes_without_recomputing(faces, tmp_path):
    out = tmp_path / "study"
    masks = ["nasal-S", "nasal-M", "nasal-L"]
    # interrupted after 4 cases (a budget stands in for a crash: the store is committed per case)
    s1 = run_study(faces, masks, out, scheduler=None, n_workers=2, processes=False, case_fn=fake_case,
                   max_new_cases=4)
    assert s1["n_computed"] == 4 and len(_rows(out)) == 4
    s2 = run_study(faces, masks, out, processes=False, case_fn=fake_case)
    assert s2["n_reused"] == 4 and s2["n_computed"] == 5 and len(_rows(out)) == 9
    s3 = run_study(faces, masks, out, processes=False, case_fn=fake_case)
    assert s3["n_computed"] == 0 and s3["n_reused"] == 9
    assert s3["n_failed"] == 3  # face_bad with each mask, kept with its error
    with open(out / "ranking.csv") as f:
        table = list(csv.DictReader(f))
    neutral = [r for r in table if r["face"] == "face_neutral"]
    assert [r["mask"] for r in sorted(neutral, key=lambda r: int(r["rank"]))] == ["nasal-M", "nasal-S", "nasal-L"]
    html = (out / "ranking.html").read_text()
    assert "face_identity000" in html and "nasal-M" in html


def test_ranking_orders_sealing_masks_by_force():
    rows = [fake_case("x/face_a.obj", m, {}) for m in _FORCE]
    ranked = ranking(rows)
    assert [r["mask"] for r in ranked] == ["nasal-M", "nasal-S", "nasal-L"]
    assert [r["rank"] for r in ranked] == [1, 2, 3]


def test_store_is_committed_per_case(tmp_path):
    store = CaseStore(tmp_path / "c.sqlite")
    store.put({"face": "f", "mask": "m", "status": "sealed"})
    # a second connection sees the row at once (nothing held back until the end of the study)
    other = CaseStore(tmp_path / "c.sqlite")
    assert other.done() == {("f", "m")}
    store.close()
    other.close()


def test_bad_study_input(tmp_path, faces):
    with pytest.raises(ParameterError):
        run_study(tmp_path / "missing", ["nasal-M"], tmp_path / "o")
    with pytest.raises(ParameterError):
        run_study(faces, ["nasal-XXL"], tmp_path / "o")
    assert StudyOptions().maximum <= 200


def test_a_store_from_before_the_leak_column_is_upgraded(tmp_path):
    path = tmp_path / "cases.sqlite"
    with sqlite3.connect(path) as db:  # the schema before least_acceptable_leak_force_n
        db.execute("""CREATE TABLE cases (face TEXT NOT NULL, mask TEXT NOT NULL, status TEXT NOT NULL, sealed INTEGER,
            least_seal_force_n REAL, peak_pressure_kpa REAL, mean_pressure_kpa REAL, contact_area_cm2 REAL,
            n_solves INTEGER, seconds REAL, error TEXT, result_json TEXT, finished_at REAL, PRIMARY KEY (face, mask))""")
        db.execute("INSERT INTO cases (face, mask, status) VALUES ('f', 'nasal-S', 'no-seal')")
    store = CaseStore(path)
    store.put({"face": "f", "mask": "nasal-M", "status": "sealed", "least_acceptable_leak_force_n": 7.5,
               "acceptable_leak_up_to_n": 17.5})
    rows = {r["mask"]: r for r in store.rows()}
    store.close()
    assert rows["nasal-M"]["least_acceptable_leak_force_n"] == 7.5
    assert rows["nasal-M"]["acceptable_leak_up_to_n"] == 17.5  # the window's top (search module doc)
    assert rows["nasal-S"]["least_acceptable_leak_force_n"] is None and rows["nasal-S"]["status"] == "no-seal"


def test_a_resumed_study_refuses_other_settings(faces, tmp_path):
    """Cases computed with one contact model (or force range, mesh size...) are never mixed with
    another's in one store: the second run stops with the differing settings named."""
    out = tmp_path / "study"
    run_study(faces, ["nasal-M"], out, processes=False, case_fn=fake_case, max_new_cases=1)
    with pytest.raises(ParameterError, match="contact='barrier'.*contact='planes'"):
        run_study(faces, ["nasal-M"], out, options=StudyOptions(contact="planes"), processes=False,
                  case_fn=fake_case)
    with pytest.raises(ParameterError, match="rotate=True.*rotate=False"):
        run_study(faces, ["nasal-M"], out, options=StudyOptions(rotate=False), processes=False, case_fn=fake_case)
    with pytest.raises(ParameterError, match="maximum"):
        run_study(faces, ["nasal-M"], out, options=StudyOptions(maximum=40.0), processes=False, case_fn=fake_case)
    # the same settings resume
    s = run_study(faces, ["nasal-M"], out, processes=False, case_fn=fake_case)
    assert s["n_reused"] == 1 and s["n_computed"] == 2


def test_a_store_without_recorded_settings_resumes_only_at_the_defaults(tmp_path):
    path = tmp_path / "cases.sqlite"
    store = CaseStore(path)
    store.put({"face": "f", "mask": "nasal-S", "status": "no-seal"})
    store._db.execute("DELETE FROM settings")  # as a store written before settings were recorded
    store._db.commit()
    with pytest.raises(ParameterError, match="friction"):
        store.check_settings(StudyOptions(friction=0.5, contact="planes"))
    # such a store was computed when the planes were the default contact
    with pytest.raises(ParameterError, match="contact='planes'"):
        store.check_settings(StudyOptions())
    store.check_settings(StudyOptions(contact="planes"))
    store.close()
