"""The denoiser's strength on dark frames with a noisy sensor (issue 9; docs/notes/s14-darkrows.md).

``auto`` denoises every under-exposed frame (``X>dn``) with the self-guided filter of
``canopy.enhance.noise.denoise``, ε = (``denoise_eps_factor`` · σ)², σ measured on the frame
after AFE's gain and the exposure curve. With the factor 2 a window whose grey-level std is below
~2σ counts as flat and is averaged (He et al., "Guided Image Filtering", Eq. 5: a = σ_w² / (σ_w² + ε)).

Why a second factor for noisy frames: a dark frame's texture and its noise are both lifted by the
same gain, so what the filter keeps depends on the scene's contrast over the sensor's noise. On the
clean dark-rows preset (σ after the gain 6.6–9.2) the 2σ rule removes the quantisation and read
noise and leaves the crowns' texture. With the grid's noisy sensor at full light (σ 18.3–18.8
after the gain, raw 3.1) the same rule averages every window whose std is below ~37 grey levels:
the enhanced frame comes out smoother than the clean one (robust σ 1.48 against 1.60), the corners
that remain are blurred, and the SAD sub-pixel disparities of surface points are off by more
(median |error| 0.34 → 0.51 px, > 1 px 11 → 23 %) and biased long (+0.35 % of the disparity against
+0.19 % clean), so the depths come out short and the trajectory with them (Sim(3) scale 0.9976
against 0.9993: half of the cell's 9.2 mm ATE). A factor near 1 (only windows near the noise level
itself are averaged) keeps that texture and removes the bias: dark-rows g1-b0-high 9.23 → 4.55 mm with
1.25 (second noise draw 6.93 → 5.17; factor 0.75 / 1.0 / 1.5 / 3:
5.0 / 5.1 / 6.9 / 7.3 mm). The cost: the day-loop at 15 % light, whose dark frames measure the same σ,
goes 9.99 → 11.14 mm (its bar is 11.2), and a third noise draw of dark-rows goes 5.97 → 8.22 mm: on
that 150-frame cell the scale moves by ±0.2 % from draw to draw (docs/notes/s14-darkrows.md, §3).

Alone (σ gate only) it is off in every shipped config: where the light is 6 %, the same σ gate opens
on frames whose texture is not above the noise, and the weaker filter leaves noise corners there:
haze-row at 6 % light with the noisy sensor 96 % tracked, 88.8 mm → 13 %, 6.0 m; day-loop at 6 %
43.7 → 62.0 mm (the lead's full preset grid, docs/notes/s14-lead.md). configs/synthetic.yaml turns the
gate on together with ``canopy.enhance.snr`` (s15-snr), which gives the noisy factor only to frames
whose texture stands above the noise (``snr_eps_factor``; this module's ``denoise_eps_factor`` is then
its answer over the gate when that rule is off).

The gate is the σ the denoiser measures, so the clean presets never reach it (every dark frame of the
clean day-loop, dusk-loop, haze-row and dark-rows: ≤ 9.2, see the note) and keep the factor 2 bit for
bit; the noisy cells' dark frames measure ≥ 13.7. ``denoise_noisy_sigma`` 0 (the default) = off.
"""
from __future__ import annotations

import numpy as np

from canopy.enhance.noise import denoise
from canopy.enhance.params import EnhanceParams


def denoise_eps_factor(sigma: float, params: EnhanceParams) -> float:
    """ε factor of the denoiser for a frame whose (post-gain) noise σ is ``sigma``:
    ``denoise_eps_factor_noisy`` when ``denoise_noisy_sigma`` > 0 and σ ≥ it, else ``denoise_eps_factor``."""
    gate = params.denoise_noisy_sigma
    if gate > 0.0 and float(sigma) >= gate:
        return params.denoise_eps_factor_noisy
    return params.denoise_eps_factor


def denoise_frame(image: np.ndarray, sigma: float, params: EnhanceParams,
                  eps_factor: float | None = None) -> np.ndarray:
    """``denoise`` with the radius of ``params`` and the ε factor ``eps_factor`` (the left image's, for
    the right image of a pair: ``canopy.enhance.snr.snr_eps_factor``), by default that of
    ``denoise_eps_factor``."""
    factor = denoise_eps_factor(sigma, params) if eps_factor is None else float(eps_factor)
    return denoise(image, sigma, params.denoise_radius, factor)
