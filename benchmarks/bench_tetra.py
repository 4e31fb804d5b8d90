import time, sys, numpy as np
from headsim.mesh.primitives import icosphere, box
from headsim.mesh import SurfaceMesh
from headsim.mesh.tetra import tetrahedralize_surface
from headsim.mesh.quality import tet_quality

def bumpy(div=29, R=0.05):
    b = box((2, 2, 2), div)
    u = b.vertices / np.linalg.norm(b.vertices, axis=1, keepdims=True)
    th = np.arccos(u[:, 2]); ph = np.arctan2(u[:, 1], u[:, 0])
    r = R * (1 + 0.2 * np.sin(5 * th) * np.cos(4 * ph))
    return SurfaceMesh(u * r[:, None], b.triangles, name="bumpy")

cases = [("icosphere r=5cm s=3", icosphere(0.05, 3)), ("box 10x6x4 cm div 8", box((0.1, 0.06, 0.04), 8)), ("bumpy sphere", bumpy())]
from headsim.mesh.tetra import _default_edge
configs = {"gmsh": dict(method="gmsh"), "tetwild": dict(method="tetwild"),
           "tetwild-fast": dict(method="tetwild", stop_energy=20.0, optimize_iterations=20),
           "tetwild-fine": "fine"}
which = sys.argv[1:] or list(configs)
for name, s in cases:
    vs = s.signed_volume()
    for meth in which:
        t = time.perf_counter(); c = time.process_time()
        try:
            cfg = configs[meth]
            if cfg == "fine":
                if s.n_triangles > 5000:
                    continue
                cfg = dict(method="tetwild", target_edge=_default_edge(s))
            tm = tetrahedralize_surface(s, **cfg)
        except Exception as e:
            print(name, meth, "ERR", e); continue
        dt = time.perf_counter() - t; dc = time.process_time() - c
        q = tet_quality(tm).summary()
        print(f"{name:22s} tri={s.n_triangles:6d} {meth:12s} wall={dt:6.2f}s cpu={dc:6.2f}s tets={tm.n_tets:7d} verts={tm.n_vertices:6d} "
              f"mindih={q['min_dihedral_deg']:5.2f} p1dih={q['dihedral_p1_deg']:5.2f} rr_min={q['radius_ratio_min']:.3f} rr_med={q['radius_ratio_median']:.3f} "
              f"volerr_vs_surface={(tm.volume - vs) / vs:+.2e}", flush=True)
