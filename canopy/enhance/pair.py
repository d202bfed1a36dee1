"""A stereo pair through the enhancement, optionally the two images on two threads (issue 9: ≤ 4 ms a pair).

Both images of a pair must get the same treatment (stereo matching compares them): ``auto``
decides on the left image, and the right one gets that decision, the left image's exposure γ
and noise σ (``make_enhancer`` + ``pair_arguments`` do this one image after the other).
``PairEnhancer`` computes exactly the same images, but splits ``auto`` into its steps so that
the per-pixel work of the two images runs side by side (OpenCV and numpy release the GIL):

1. decision from the left image's statistics (¼-scale copy, ~0.2 ms);
2. both images: the decided method (AFE, dehazing, ...)            — in parallel;
3. from the left result: exposure γ and noise σ (cheap: a mean, a noise estimate on half the rows);
4. both images: exposure curve and denoiser with that γ and σ      — in parallel.

Other methods: the method on both images in parallel.
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from canopy.enhance.auto import _APPLY, _clipped_fraction, apply_gamma, auto_decide, exposure_gamma
from canopy.enhance.common import check_image, mean_std
from canopy.enhance.factory import METHOD_FUNCTIONS
from canopy.enhance.noise import estimate_noise
from canopy.enhance.noisy_dark import denoise_frame  # s14-darkrows hook: the ε factor by σ
from canopy.enhance.params import EnhanceParams
from canopy.enhance.snr import lit_denoise_wanted, snr_eps_factor  # s15-snr: one ε factor for both images, from the left; s16: lit frames


class PairEnhancer:
    """``enhance(left, right) -> (left', right', info)``; ``info`` as ``make_enhancer``'s for the
    left image (decision, statistics, σ, γ), with ``ms`` the wall time of the whole pair."""

    def __init__(self, params: EnhanceParams | None = None, parallel: bool | None = None):
        """``parallel``: the two images on two threads; None = as ``params.pair_threads`` says."""
        self.params = params or EnhanceParams()
        self.params.validate()
        if parallel is None:
            parallel = self.params.pair_threads > 1
        self._pool = ThreadPoolExecutor(max_workers=1) if parallel else None

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def _both(self, fn, left, right):
        """(fn(left), fn(right)); the right one on the worker thread when parallel."""
        if self._pool is None:
            return fn(left), fn(right)
        job = self._pool.submit(fn, right)
        return fn(left), job.result()

    def _auto(self, left, right):
        p = self.params
        decision, st = auto_decide(left, p)
        dark = st["mean"] < p.auto_dark_mean
        base_l, base_r = self._both(lambda im: _APPLY[decision](im, p), left, right)
        if decision == "dehaze" and _clipped_fraction(base_l) - _clipped_fraction(left) > p.auto_dehaze_max_clip:
            decision = "afe"  # the haze guard of auto_full, step 2
            base_l, base_r = self._both(lambda im: _APPLY[decision](im, p), left, right)
        if not dark and not p.auto_denoise_lit:
            return base_l, base_r, decision, 0.0, 1.0, 0.0
        gamma = exposure_gamma(base_l, p.auto_dark_target_mean, p.auto_dark_min_gamma) if dark else 1.0
        lifted_l = apply_gamma(base_l, gamma)
        sigma = estimate_noise(lifted_l, rows_fraction=p.noise_rows_fraction)
        if dark:
            sigma = max(sigma, p.auto_dark_min_sigma)
        elif not lit_denoise_wanted(lifted_l, sigma, p):
            return base_l, base_r, decision, 0.0, 1.0, 0.0
        factor = snr_eps_factor(lifted_l, sigma, p)

        def finish(pair_side):
            image, lifted = pair_side
            lifted = apply_gamma(image, gamma) if lifted is None else lifted
            return denoise_frame(lifted, sigma, p, factor)
        out_l, out_r = self._both(finish, (base_l, lifted_l), (base_r, None))
        return out_l, out_r, decision + ">dn", sigma, gamma, factor

    def __call__(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
        left, right = check_image(left, "left image"), check_image(right, "right image")
        start = time.perf_counter()
        p = self.params
        if p.method == "auto":
            out_l, out_r, used, sigma, gamma, factor = self._auto(left, right)
        else:
            fn = METHOD_FUNCTIONS[p.method]
            out_l, out_r = self._both(lambda im: fn(im, p), left, right)
            used, sigma, gamma, factor = p.method, 0.0, 1.0, 0.0
        ms = (time.perf_counter() - start) * 1e3
        mean_in, std_in = mean_std(left)
        mean_out, std_out = mean_std(out_l)
        return out_l, out_r, {"method": used, "requested": p.method, "mean_in": mean_in, "std_in": std_in,
                              "mean_out": mean_out, "std_out": std_out, "noise_sigma": sigma, "gamma": gamma,
                              "eps_factor": factor, "ms": ms}
