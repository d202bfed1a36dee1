"""s17-kittihaze: ATE (mm) / tracked % per variant and seed from diag.sh SUMMARY files. Usage: table.py FILES..."""
import json, re, sys
from collections import defaultdict
rows = defaultdict(dict)
for f in sys.argv[1:]:
    for line in open(f):
        if "SUMMARY" not in line:
            continue
        name, _, cell = line.split()[:3]
        d = json.loads(line[line.index("{"):])
        seed = re.search(r"seed(\d+)", cell).group(1)
        cell = re.sub(r"kitti-all-|-seed\d+", "", cell)
        rows[(name, cell)][seed] = d["ate_mm"] if d["tracked"] >= 100 else f"{d['ate_mm']:.0f}({d['tracked']:.0f}%)"
for (name, cell), r in sorted(rows.items(), key=lambda kv: (kv[0][1], kv[0][0])):
    vals = [r.get(str(s)) for s in range(5)]
    nums = [v for v in vals if isinstance(v, float)]
    print(f"{cell:18s} {name:12s} " + " ".join(f"{v:8.1f}" if isinstance(v, float) else f"{v or '-':>8s}" for v in vals)
          + (f"  mean {sum(nums)/len(nums):7.1f}" if len(nums) == len([v for v in vals if v is not None]) and nums else ""))
