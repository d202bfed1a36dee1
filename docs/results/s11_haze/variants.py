"""Run enhancement variants on cached degraded cells in process (bench_enhance_diagnose.run, as the grid);
one JSON line per run. Usage: variants.py CELL DATASET V1,V2,... [enh.NAME=VALUE] [trk.NAME=VALUE] [chain=1]
Variants force one decision of auto (table VARIANTS); "@lit" also turns the dark branch off."""
import json, sys, time
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from benchmarks.bench_enhance_diagnose import run
from canopy.config import parse_value
from canopy.sources import BUNDLED_DATA

VARIANTS = {
    "auto": {},
    "dehaze": dict(auto_low_std=255.0, auto_haze_dark=0.0, auto_dehaze_max_clip=1.0),
    "dehaze>dn": dict(auto_low_std=255.0, auto_haze_dark=0.0, auto_dehaze_max_clip=1.0, auto_denoise_lit=True, auto_noise_sigma=0.0),
    "none>dn": dict(auto_low_std=0.0, auto_bright_mean=255.0, auto_denoise_lit=True, auto_noise_sigma=0.0),
    "afe": dict(auto_low_std=255.0, auto_haze_dark=255.0),
    "afe>dn": dict(auto_low_std=255.0, auto_haze_dark=255.0, auto_denoise_lit=True, auto_noise_sigma=0.0),
    "none": dict(method="none"),
    "clahe": dict(method="clahe"),
    "agri": dict(method="agri"),
}

def chain_dehaze_afe():
    """experiment: the dark branch's AFE on the dehazed frame (dehaze, then AFE curve, gamma, denoise)."""
    import importlib; A = importlib.import_module("canopy.enhance.auto")
    from canopy.enhance.dehaze import dehaze_dark_channel
    afe = A._APPLY["afe"]
    A._APPLY["afe"] = lambda image, params: afe(dehaze_dark_channel(image, params), params)


def main():
    cache = Path('/work/cache/degraded')
    cell, dataset = sys.argv[1], sys.argv[2]
    variants = sys.argv[3].split(',')
    extra = dict(kv.split('=', 1) for kv in sys.argv[4:])
    if extra.pop('chain', None):
        chain_dehaze_afe()
    enh_extra = {k[4:]: parse_value(v) for k, v in extra.items() if k.startswith('enh.')}
    trk_extra = {k[4:]: parse_value(v) for k, v in extra.items() if k.startswith('trk.')}
    if dataset in ('kitti', 'euroc'):
        clean, config, kind = BUNDLED_DATA[dataset], dataset, dataset
    else:
        clean, config, kind = Path(f'/work/cache/synthetic/{dataset}-seed0-full'), 'synthetic', 'euroc'
    mf = {'day-loop': 300, 'haze-row': 346, 'dark-rows': 150}.get(dataset)
    for v in variants:
        name, _, dark_off = v.partition('@')   # "@lit": auto_dark_mean=0 so dark frames take the lit rules
        sets = {"method": "auto", **VARIANTS[name], **enh_extra}
        if dark_off:
            sets["auto_dark_mean"] = 0.0
        t = time.time()
        out, rows = run(cell if cell.startswith('/') else cache / cell, clean, config, sets, trk_extra, mf, stereo=False, kind=kind)
        dec = {}
        for r in rows:
            dec[r['method']] = dec.get(r['method'], 0) + 1
        sig = [r['sigma'] for r in rows if r['sigma']]
        print(json.dumps({"cell": cell, "variant": v, "extra": extra, "tracked": round(100*out['tracked'], 1),
                          "ate_mm": None if out.get('ate') is None else round(1000*out['ate'], 1),
                          "sim3_mm": None if out.get('ate_sim3') is None else round(1000*out['ate_sim3'], 1),
                          "dec": dec, "sigma_med": round(sorted(sig)[len(sig)//2], 2) if sig else 0,
                          "s": round(time.time()-t)}), flush=True)

main()
