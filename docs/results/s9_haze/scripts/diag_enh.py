import sys, json
sys.path.insert(0, ".")
from benchmarks.bench_enhance_diagnose import run
from canopy.sources import BUNDLED_DATA
path, clean, cfg, n = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
enh = {"method": "auto", **{a.split("=")[0]: json.loads(a.split("=")[1]) for a in sys.argv[5:]}}
kind = "kitti" if cfg == "kitti" else "euroc"
out, rows = run(path, clean if clean != "-" else BUNDLED_DATA["kitti"], cfg, enh, {}, n or None, stereo=False, kind=kind)
dec = {}
for r in rows: dec[r["method"]] = dec.get(r["method"], 0) + 1
print(path, enh, json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in out.items() if k in ("tracked", "ate", "ate_sim3", "scale", "med_inl")}), dec)
