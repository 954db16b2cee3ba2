"""Compare the surrogate DIGIT with the real reference measurements in ``../shared/real``.

The reference files are never part of the project: every function here takes their
location, returns plain dicts of numbers, and returns ``None`` (or the caller skips) when
they are absent. The fitting functions are the ones that produced the constants embedded
in ``sensor/background.py`` and ``effects/_optics_fit.py``, kept so the fit can be redone
and checked.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from tactile_bench.effects._optics_fit import N_HARM, N_MAG, RESPONSE_WEIGHTS
from tactile_bench.effects.optics import fitted_response
from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.images import RGB_MODES, open_image
from tactile_bench.io import load_npz
from tactile_bench.sensor.background import digit_background

BACKGROUND_FILE = "digit_background_240x320.jpg"
POLYCALIB_FILE = "digit_polycalib.npz"
# Taxim's polycalib pixel frame, taken as the DIGIT portrait frame (240 wide x 320 high),
# the orientation of TACTO's background and of this project's 18 x 24 mm gel.
POLY_FRAME_W, POLY_FRAME_H = 240, 320


def default_real_dir() -> Path | None:
    """The reference folder: ``$TACTILE_BENCH_REAL_DIR`` or ``../shared/real`` near the repo."""
    env = os.environ.get("TACTILE_BENCH_REAL_DIR")
    candidates = [Path(env)] if env else []
    here = Path(__file__).resolve()
    candidates += [p / "shared" / "real" for p in here.parents[:5]]
    candidates.append(Path.cwd().parent / "shared" / "real")
    for c in candidates:
        if (c / BACKGROUND_FILE).exists() or (c / POLYCALIB_FILE).exists():
            return c
    return None


def load_real_background(real_dir: Path | str | None = None) -> np.ndarray | None:
    """The real no-contact frame as float (H=320, W=240, 3) in 0..255, or None if absent."""
    d = Path(real_dir) if real_dir is not None else default_real_dir()
    if d is None or not (d / BACKGROUND_FILE).exists():
        return None
    im = open_image(d / BACKGROUND_FILE)  # a corrupt file is a one-line error naming it
    if im.mode not in RGB_MODES or im.size != (POLY_FRAME_W, POLY_FRAME_H):
        raise TactileBenchError(
            f"{d / BACKGROUND_FILE}: {im.size[0]} x {im.size[1]} {im.mode}; expected a "
            f"{POLY_FRAME_W} x {POLY_FRAME_H} RGB DIGIT frame"
        )
    return np.asarray(im.convert("RGB")).astype(np.float64)


def load_polycalib(real_dir: Path | str | None = None) -> np.ndarray | None:
    """Taxim's table as (3, 125, 125, 6): channel, |grad| bin, direction bin, raw coefficients."""
    d = Path(real_dir) if real_dir is not None else default_real_dir()
    if d is None or not (d / POLYCALIB_FILE).exists():
        return None
    z = load_npz(d / POLYCALIB_FILE, ("grad_r", "grad_g", "grad_b"))
    try:
        table = np.stack([z["grad_r"], z["grad_g"], z["grad_b"]], 0).astype(np.float64)
    except (ValueError, TypeError) as exc:
        raise TactileBenchError(f"{d / POLYCALIB_FILE}: grad_r/g/b differ ({exc})") from None
    if table.ndim != 4 or table.shape[-1] != 6 or not np.isfinite(table).all():
        raise TactileBenchError(
            f"{d / POLYCALIB_FILE}: expected finite (bins, bins, 6) tables, got {table.shape[1:]}"
        )
    return table


# ----------------------------------------------------------------------------- background
def _dct_basis(n: int, k: int) -> np.ndarray:
    t = (np.arange(n) + 0.5) / n
    return np.stack([np.cos(np.pi * i * t) for i in range(k)], 1)


def fit_background_dct(image: np.ndarray, k: int = 6) -> np.ndarray:
    """Least-squares k x k cosine coefficients (3, k_y, k_x) of an (H, W, 3) frame."""
    h, w = image.shape[:2]
    a = np.einsum("yk,xl->yxkl", _dct_basis(h, k), _dct_basis(w, k)).reshape(h * w, k * k)
    coef = np.linalg.lstsq(a, image.reshape(h * w, 3), rcond=None)[0]
    return coef.T.reshape(3, k, k)


def background_report(real_dir: Path | str | None = None, unit: str = "digit") -> dict | None:
    """Per-channel mean/std of the real frame and of the surrogate's, and the field RMSE.

    ``lowfreq_rmse`` compares the surrogate's field with a low-pass (Gaussian, sigma 8 px at
    240 x 320) of the real frame, i.e. the part a colour-field model can represent;
    ``rmse`` compares with the raw frame (includes JPEG texture and sharp rim features).
    """
    from scipy.ndimage import gaussian_filter

    real = load_real_background(real_dir)
    if real is None:
        return None
    h, w = real.shape[:2]
    ours = digit_background((h, w), unit=unit).permute(1, 2, 0).numpy().astype(np.float64)
    low = gaussian_filter(real, (8, 8, 0))
    return {
        "real_mean": real.mean((0, 1)).tolist(),
        "real_std": real.std((0, 1)).tolist(),
        "surrogate_mean": ours.mean((0, 1)).tolist(),
        "surrogate_std": ours.std((0, 1)).tolist(),
        "mean_abs_diff_of_means": float(np.abs(real.mean((0, 1)) - ours.mean((0, 1))).mean()),
        "rmse": float(np.sqrt(((real - ours) ** 2).mean())),
        "lowfreq_rmse": float(np.sqrt(((low - ours) ** 2).mean())),
    }


# ----------------------------------------------------------------------- optical response
def polycalib_normalised(table: np.ndarray) -> np.ndarray:
    """Re-express Taxim's raw-pixel polynomials in normalised coordinates.

    Returns (3, 125, 125, 6) coefficients of (1, u, v, u^2, v^2, u v) with u, v in [-1, 1]
    across the frame width / height (u right, v down).
    """
    cx, cy = (POLY_FRAME_W - 1) / 2, (POLY_FRAME_H - 1) / 2
    hx, hy = cx, cy
    a, b, c, dx, dy, e = (table[..., i] for i in range(6))
    one = a * cx**2 + b * cy**2 + c * cx * cy + dx * cx + dy * cy + e
    u = (2 * a * cx + c * cy + dx) * hx
    v = (2 * b * cy + c * cx + dy) * hy
    return np.stack([one, u, v, a * hx**2, b * hy**2, c * hx * hy], -1)


def polycalib_bin_centres(bins: int = 125) -> tuple[np.ndarray, np.ndarray]:
    """Slope angle (rad) and direction (rad) at the centres of Taxim's bins."""
    m = np.minimum((np.arange(bins) + 0.5) * (np.pi / 2) / (bins - 1), np.pi / 2)
    phi = -np.pi + (np.arange(bins) + 0.5) * 2 * np.pi / (bins - 1)
    return m, phi


def response_features_np(m: np.ndarray, phi: np.ndarray, n_mag: int = 3, n_harm: int = 3):
    """Features of the compact model: [contact offset] + t^j x harmonics(phi), t = m/(pi/2)."""
    t = m / (np.pi / 2)
    harms = [np.ones_like(phi)]
    for k in range(1, n_harm + 1):
        harms += [np.cos(k * phi), np.sin(k * phi)]
    feats = [np.ones_like(m)] + [t ** (j + 1) * h for j in range(n_mag) for h in harms]
    return np.stack(feats, -1)


def fit_optical_response(table: np.ndarray, n_mag: int = 3, n_harm: int = 3) -> np.ndarray:
    """Least-squares weights (F, 3, 6): feature x channel x position term."""
    q = polycalib_normalised(table)
    m, phi = polycalib_bin_centres(table.shape[1])
    mm, pp = np.meshgrid(m, phi, indexing="ij")
    f = response_features_np(mm, pp, n_mag, n_harm).reshape(-1, 1 + n_mag * (2 * n_harm + 1))
    y = q.transpose(1, 2, 0, 3).reshape(f.shape[0], 18)
    w = np.linalg.lstsq(f, y, rcond=None)[0]
    return w.reshape(-1, 3, 6)


def _position_grid(nu: int = 9, nv: int = 11) -> np.ndarray:
    uu, vv = np.meshgrid(np.linspace(-1, 1, nu), np.linspace(-1, 1, nv), indexing="xy")
    return np.stack([np.ones_like(uu), uu, vv, uu**2, vv**2, uu * vv], -1).reshape(-1, 6)


def optical_response_report(real_dir: Path | str | None = None) -> dict | None:
    """Mean abs colour error (0-255) of the embedded compact response vs the real table.

    Evaluated over all 125 x 125 gradient bins at a 9 x 11 grid of positions spanning the
    frame; also restricted to slopes below 60 deg (the range a ball calibration observes).
    """
    table = load_polycalib(real_dir)
    if table is None:
        return None
    q = polycalib_normalised(table)
    m, phi = polycalib_bin_centres(table.shape[1])
    mm, pp = np.meshgrid(m, phi, indexing="ij")
    f = response_features_np(mm, pp, N_MAG, N_HARM)
    w = np.asarray(RESPONSE_WEIGHTS, dtype=np.float64)
    pos = _position_grid()
    true = np.einsum("cijq,kq->cijk", q, pos)
    est = np.einsum("ijf,fcq,kq->cijk", f, w, pos)
    err = np.abs(est - true)
    low = mm < np.deg2rad(60)
    return {
        "mae": float(err.mean()),
        "mae_below_60deg": float(err[:, low].mean()),
        "mae_per_channel": err.mean(axis=(1, 2, 3)).tolist(),
        "table_mean_abs": float(np.abs(true).mean()),
        "relative_error": float(err.mean() / np.abs(true).mean()),
        "n_numbers_embedded": int(w.size),
    }


def surrogate_response_report(
    real_dir: Path | str | None = None, grid: tuple[int, int] = (5, 6)
) -> dict | None:
    """Error of the surrogate's torch response (as rendered) vs the table, at bin centres.

    Exercises the same code path the surrogate renders with, so a unit or sign mistake in
    the torch implementation shows up here and not only in the numpy fit. ``grid`` is the
    number of positions across x and y (coarser than the fit report's 9 x 11, for speed).
    """
    table = load_polycalib(real_dir)
    if table is None:
        return None
    q = polycalib_normalised(table)
    m, phi = polycalib_bin_centres(table.shape[1])
    mm, pp = np.meshgrid(m, phi, indexing="ij")
    pos = _position_grid(*grid)
    true = np.einsum("cijq,kq->cijk", q, pos)  # (3, 125, 125, K)
    slope = np.tan(np.minimum(mm, np.deg2rad(89.5)))
    gx = torch.tensor(slope * np.cos(pp), dtype=torch.float32).reshape(-1)
    gy = torch.tensor(slope * np.sin(pp), dtype=torch.float32).reshape(-1)
    u = torch.tensor(pos[:, 1], dtype=torch.float32)
    v = torch.tensor(pos[:, 2], dtype=torch.float32)
    est = fitted_response(
        gx[:, None], gy[:, None], u[None, :], v[None, :], torch.ones(1, 1)
    )  # (3, B, K)
    est = est.reshape(3, *mm.shape, -1).double().numpy()
    err = np.abs(est - true)
    return {"mae": float(err.mean()), "mae_below_60deg": float(err[:, mm < np.deg2rad(60)].mean())}


def grounding_report(real_dir: Path | str | None = None) -> dict:
    """All grounding numbers; sections are None when the reference file is absent."""
    return {
        "background": background_report(real_dir),
        "background_digit_b": background_report(real_dir, unit="digit-b"),
        "optical_response": optical_response_report(real_dir),
        "surrogate_response": surrogate_response_report(real_dir),
    }
