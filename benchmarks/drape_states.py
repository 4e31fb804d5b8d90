"""Saved drape states for the benchmarks: a :class:`~headsim.solvers.chains.ChainState` in a compressed ``.npz``
(float32 positions m, unit quaternions (x, y, z, w) of the rotations, velocities m/s and rad/s; the time s
in float64), so that a benchmark can start from a state that takes an hour or more to reach (the reference
strand at rest) instead of re-running the sequence.

The float32 rounding moves a 30 cm strand's segment centres by ≤ 1e-8 m and its rotations by ≈ 1e-7 rad,
which opens the joints by ≲ 1e-8 m: the first step's joint stage closes that. A run from a loaded state is
therefore a run from a nearby state, not the saved trajectory bitwise; it also starts cold (no warm-start
impulses, no previous step's band allowance), so time the steps after a few warm-up steps.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

# m: a saved state whose anchored fibres start farther than this from the model's roots belongs to another scene
# (the root joints of the saved runs stay within microns; fibres of the 1.5 d and 3 d lattices differ by up to mm)
ROOT_MISMATCH = 1e-4


def save_state(path, state) -> Path:
    """Write ``state`` (a ChainState) to ``path`` (.npz); returns the path."""
    from scipy.spatial.transform import Rotation

    path = Path(path)
    q = Rotation.from_matrix(state.rotation).as_quat()
    tmp = path.with_name(path.name + ".tmp.npz")
    try:
        np.savez_compressed(tmp, time=np.float64(state.time), position=state.position.astype(np.float32),
                            quaternion=q.astype(np.float32), velocity=state.velocity.astype(np.float32),
                            angular_velocity=state.angular_velocity.astype(np.float32))
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)  # no partial file, also when the write fails
    return path


def load_state(path, model):
    """The ChainState saved in ``path`` for ``model`` (a ChainModel); SystemExit with a clear message when the
    file does not exist or holds another number of segments."""
    from scipy.spatial.transform import Rotation

    from headsim.solvers.chains import ChainState

    path = Path(path)
    if not path.is_file():
        raise SystemExit(f"no saved state at {path}")
    with np.load(path) as d:
        n = len(d["position"])
        if n != model.n_segments:
            raise SystemExit(f"{path} holds {n} segments, the scene has {model.n_segments}: use the same "
                             "--fibres and --segments as the run that saved it")
        rotation = Rotation.from_quat(d["quaternion"].astype(np.float64)).as_matrix()
        position = d["position"].astype(np.float64)
        # the anchored fibres' first segments must start at this model's roots (a state of another scene, e.g.
        # another fibre spacing, would otherwise load and tear every root joint open in its first step)
        anchored = np.asarray(model.anchored)
        first = np.asarray(model.segment_offsets[:-1])[anchored]
        ends = position[first] - model.half_length[first, None] * rotation[first, :, 2]
        off_root = np.linalg.norm(ends - np.asarray(model.root_point)[anchored], axis=1)
        if off_root.size and off_root.max() > ROOT_MISMATCH:
            raise SystemExit(f"{path}: its fibres start up to {off_root.max() * 1e3:.2g} mm from this scene's roots: "
                             "it was saved from another scene (use the same --fibre-spacing and --geometry)")
        return ChainState(position, rotation, d["velocity"].astype(np.float64),
                          d["angular_velocity"].astype(np.float64), float(d["time"]))
