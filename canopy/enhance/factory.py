"""Enhancement methods chosen by name from the config (a small factory)."""
from __future__ import annotations

import time
from typing import Callable

import numpy as np

from canopy.enhance.agcwd import agcwd_unsharp
from canopy.enhance.auto import apply_decision, auto_full
from canopy.enhance.baselines import clahe, histogram_equalise, none
from canopy.enhance.common import check_image, mean_std
from canopy.enhance.dehaze import dehaze_dark_channel, dehaze_inverted
from canopy.enhance.params import AUTO_DECISIONS, EnhanceParams
from shared.errors import ConfigError

METHOD_FUNCTIONS: dict[str, Callable[[np.ndarray, EnhanceParams], np.ndarray]] = {
    "none": none,
    "he": histogram_equalise,
    "clahe": clahe,
    "afe": agcwd_unsharp,
    "agri": dehaze_inverted,
    "dehaze": dehaze_dark_channel,  # an ``auto`` decision, not a user-facing method
}


def make_enhancer(params: EnhanceParams | None = None) -> Callable[[np.ndarray], tuple[np.ndarray, dict]]:
    """Return ``enhance(image) -> (enhanced, info)`` for ``params.method``.

    ``info``: ``method`` (the method applied; for ``auto`` its per-frame
    decision), ``requested`` (``params.method``), ``mean_in``, ``std_in``,
    ``mean_out``, ``std_out`` (grey level / luma), ``noise_sigma`` (the σ
    the denoiser used, 0 if none) and ``ms`` (time of the
    enhancement call itself, statistics excluded).
    """
    params = params or EnhanceParams()
    params.validate()
    requested = params.method

    if requested == "auto":
        def apply(image):
            return auto_full(image, params)
    else:
        fn = METHOD_FUNCTIONS[requested]

        def apply(image):
            return fn(image, params), requested, 0.0

    def enhance(image: np.ndarray, method: str | None = None,
                noise_sigma: float | None = None) -> tuple[np.ndarray, dict]:
        """``method`` forces a decision (a method or an ``auto`` decision such
        as ``agri>dn``), e.g. the right image of a stereo pair gets the
        treatment ``auto`` chose for the left one; ``noise_sigma`` then passes
        the left image's noise σ so both are denoised alike."""
        image = check_image(image)
        start = time.perf_counter()
        if method is None:
            out, used, sigma = apply(image)
        elif method in METHOD_FUNCTIONS:
            out, used, sigma = METHOD_FUNCTIONS[method](image, params), method, 0.0
        elif method in AUTO_DECISIONS:
            out, sigma = apply_decision(image, method, params, noise_sigma)
            used = method
        else:
            raise ConfigError("method", f"unknown enhancement {method!r}; "
                                        f"known: {', '.join(sorted(set(METHOD_FUNCTIONS) | set(AUTO_DECISIONS)))}")
        ms = (time.perf_counter() - start) * 1e3
        mean_in, std_in = mean_std(image)
        mean_out, std_out = mean_std(out)
        return out, {"method": used, "requested": requested, "mean_in": mean_in, "std_in": std_in,
                     "mean_out": mean_out, "std_out": std_out, "noise_sigma": sigma, "ms": ms}

    return enhance
