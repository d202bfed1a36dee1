import sys
sys.path.insert(0, ".")
from benchmarks.bench_enhance_diagnose import run
path, clean, n, a, b = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
out, rows = run(path, clean, "synthetic", {"method": "auto"}, {}, n, per_frame=False, stereo=True, kind="euroc")
for r in rows[a:b]:
    print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()})
