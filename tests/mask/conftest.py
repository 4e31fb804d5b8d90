"""Shared fixtures for the mask tests: bundled faces and their landmarks (computed once)."""

import sys
from pathlib import Path

import pytest

from headsim.data import face_path, population_paths
from headsim.mask import find_landmarks
from headsim.mesh.io import load_surface

# the shared small fit problem (tests/mask/_fit_case.py): importable from every test file here, also one run alone
sys.path.insert(0, str(Path(__file__).parent))

FACE_NAMES = ["neutral", "identity000", "identity001"] + [p.stem.replace("face_", "") for p in population_paths()]


@pytest.fixture(scope="session")
def neutral_face():
    return load_surface(face_path("neutral"))


@pytest.fixture(scope="session")
def neutral_landmarks(neutral_face):
    return find_landmarks(neutral_face)


@pytest.fixture(scope="session")
def bundled_faces(neutral_face):
    return {name: neutral_face if name == "neutral" else load_surface(face_path(name)) for name in FACE_NAMES}


@pytest.fixture(scope="session")
def bundled_landmarks(bundled_faces, neutral_landmarks):
    return {name: neutral_landmarks if name == "neutral" else find_landmarks(face)
            for name, face in bundled_faces.items()}
