import sys, json
from benchmarks.bench_enhance_diagnose import run
sets = {}
for a in sys.argv[1:]:
    k, v = a.split("=", 1)
    try: v = json.loads(v)
    except Exception: pass
    sets[k] = v
enh = {k[4:]: v for k, v in sets.items() if k.startswith("enh.")}
trk = {k: v for k, v in sets.items() if not k.startswith("enh.")}
out, rows = run("/work/cache/degraded/dark-rows-150-g1-b0.06-high-seed0", "/work/cache/synthetic/dark-rows-seed0-full",
                "synthetic", {"method": "auto", **enh}, trk, 150, per_frame=True, stereo=bool(int(__import__("os").environ.get("STEREO", "1"))), kind="euroc")
print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in out.items()}))
