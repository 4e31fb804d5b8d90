import pytest

from headsim.data import face_path
from headsim.graft import bundled_markers_path, load_markers, region_from_markers
from headsim.mesh.io import load_surface


@pytest.fixture(scope="session")
def face():
    return load_surface(face_path("neutral"))


@pytest.fixture(scope="session")
def cheek_markers():
    return load_markers(bundled_markers_path())


@pytest.fixture(scope="session")
def left_cheek(face, cheek_markers):
    return region_from_markers(face, cheek_markers["left_cheek"])
