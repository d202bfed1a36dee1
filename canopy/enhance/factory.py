"""Enhancement methods chosen by name from the config (a small factory)."""
from __future__ import annotations

import time
from typing import Callable

import numpy as np

from canopy.enhance.agcwd import agcwd_unsharp
from canopy.enhance.auto import apply_decision, auto_treat_factor
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
    the denoiser used, 0 if none), ``gamma`` (the exposure curve's power, 1 if none), ``eps_factor``
    (the denoiser's ε factor, 0 if none) and ``ms`` (time of the enhancement call itself, statistics
    excluded).
    """
    params = params or EnhanceParams()
    params.validate()
    requested = params.method

    if requested == "auto":
        def apply(image):
            return auto_treat_factor(image, params)
    else:
        fn = METHOD_FUNCTIONS[requested]

        def apply(image):
            return fn(image, params), requested, 0.0, 1.0, 0.0

    def enhance(image: np.ndarray, method: str | None = None,
                noise_sigma: float | None = None, gamma: float = 1.0,
                eps_factor: float | None = None) -> tuple[np.ndarray, dict]:
        """``method`` forces a decision (a method or an ``auto`` decision such
        as ``agri>dn``), e.g. the right image of a stereo pair gets the
        treatment ``auto`` chose for the left one; ``noise_sigma`` and
        ``gamma`` then pass the left image's noise σ and exposure γ so both
        are treated alike (``pair_arguments(info)``), and ``eps_factor`` the
        denoiser's ε factor (``canopy.enhance.snr``)."""
        image = check_image(image)
        start = time.perf_counter()
        gamma_used, factor = 1.0, 0.0
        if method is None:
            out, used, sigma, gamma_used, factor = apply(image)
        elif method in METHOD_FUNCTIONS:
            out, used, sigma = METHOD_FUNCTIONS[method](image, params), method, 0.0
        elif method in AUTO_DECISIONS:
            out, sigma = apply_decision(image, method, params, noise_sigma, gamma, eps_factor or None)
            used, gamma_used = method, (gamma if method.endswith(">dn") else 1.0)
            factor = (eps_factor or 0.0) if method.endswith(">dn") else 0.0
        else:
            raise ConfigError("method", f"unknown enhancement {method!r}; "
                                        f"known: {', '.join(sorted(set(METHOD_FUNCTIONS) | set(AUTO_DECISIONS)))}")
        ms = (time.perf_counter() - start) * 1e3
        mean_in, std_in = mean_std(image)
        mean_out, std_out = mean_std(out)
        return out, {"method": used, "requested": requested, "mean_in": mean_in, "std_in": std_in,
                     "mean_out": mean_out, "std_out": std_out, "noise_sigma": sigma, "gamma": gamma_used,
                     "eps_factor": factor, "ms": ms}

    return enhance


def pair_arguments(info: dict) -> dict:
    """What the right image of a stereo pair is enhanced with, from the left image's ``info``:
    the same decision, noise σ, exposure γ and ε factor (``enhance(right, **pair_arguments(info))``)."""
    return {"method": info["method"], "noise_sigma": info["noise_sigma"], "gamma": info.get("gamma", 1.0),
            "eps_factor": info.get("eps_factor") or None}
