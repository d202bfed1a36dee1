"""Would ``auto_denoise_lit`` (σ > auto_noise_sigma → X>dn on well-lit frames) fire on a sequence?

For every frame (left image; the right one follows the left's decision): auto's decision and, on
well-lit frames, the noise σ of the base method's output (what auto_treat measures). Prints the
decisions, the largest σ and how many frames are above the threshold.

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s11_haze/lit_sigma.py PATH [STEP]
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.config import load_run_config  # noqa: E402
from canopy.enhance.auto import _APPLY, auto_decide  # noqa: E402
from canopy.enhance.noise import estimate_noise  # noqa: E402
from canopy.sources import open_source  # noqa: E402


def main():
    path, step = Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 1
    p = load_run_config("synthetic").enhancement
    src = open_source("euroc", path)
    decisions, sigmas = {}, []
    for i in range(0, len(src), step):
        img = src.frame(i).left
        dec, st = auto_decide(img, p)
        decisions[dec] = decisions.get(dec, 0) + 1
        if st["mean"] >= p.auto_dark_mean:
            sigmas.append((estimate_noise(_APPLY[dec](img, p), rows_fraction=p.noise_rows_fraction), i, dec))
    above = sum(s > p.auto_noise_sigma for s, _, _ in sigmas)
    top = "max σ {:.2f} (frame {}, {})".format(*max(sigmas)) if sigmas else "no σ measured"
    print(f"{path.name}: {len(src)} frames (every {step}), decisions {decisions}; lit frames {len(sigmas)}, "
          f"{top}, above {p.auto_noise_sigma}: {above}")


if __name__ == "__main__":
    main()
