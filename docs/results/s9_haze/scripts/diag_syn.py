import sys, json
sys.path.insert(0, ".")
from benchmarks.bench_enhance_diagnose import run
path, clean, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
out, rows = run(path, clean, "synthetic", {"method": "auto"}, {}, n, per_frame=False, stereo=False, kind="euroc")
print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in out.items()}))
bad = sorted(((r.get("dt_err") or 0, r["i"]) for r in rows), reverse=True)[:8]
print("largest per-frame dt_err:", [(i, round(e, 4)) for e, i in bad])
