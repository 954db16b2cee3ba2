"""Real sensor frames: the ball presses of a Taxim calibration data pack.

Taxim (Si & Yuan 2022, RA-L; CMURoboTouch, MIT) calibrates a GelSight by pressing a small
sphere across the gel and annotating each contact's centre and radius by hand. The ``taxim``
package (1.4.1, ``pip install -e '.[real]'``) ships two such packs, one of a GelSight and one
of a GelSight Mini, laid out as::

    <pack>/dataPack.npz   f0 (H, W, 3) uint8 no-contact frame, imgs (N, H, W, 3) uint8 presses,
                          touch_center (N, 2) x, y px, touch_radius (N,) px
    <pack>/params.json    {"sensor": {"pixmm": mm per pixel, ...}, ...}

A known sphere at a known place is a known depth image, so each press is a real (depth,
image) pair. The ball is not in the pack: Taxim's procedure names a ~4 mm sphere, and the
GelSight lineage's ``sensorParams.py`` of the same lab uses ``ball_radius = 4.00 / 2`` mm,
the default here (``ball_radius_mm`` overrides it). The cap at the annotated radius r gives
the press depth: ``d = R - sqrt(R^2 - r^2)``.

The data files are never copied into this project; this module reads them where they lie.
"""

from __future__ import annotations

import importlib.util
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
import torch.nn.functional as F

from tactile_bench.data.paired import Pairs
from tactile_bench.errors import TactileBenchError
from tactile_bench.io import load_npz

#: sensor name -> folder under ``taxim/calib/``
TAXIM_SENSORS: dict[str, str] = {"gelsight": "gelsight", "gelsight-mini": "gelsight_mini"}
#: 4 mm calibration sphere (Taxim's procedure; the lab's sensorParams ball_radius = 4.00/2)
DEFAULT_BALL_RADIUS_MM = 2.0
PACK_FILE = "dataPack.npz"
PARAMS_FILE = "params.json"
MAX_SIDE = 4096  # refuse absurd output sizes before allocating


def taxim_pack_dir(sensor: str) -> Path:
    """The installed ``taxim`` package's calibration folder for ``sensor``."""
    if sensor not in TAXIM_SENSORS:
        raise TactileBenchError(
            f"{sensor!r}: unknown Taxim sensor; known: {', '.join(TAXIM_SENSORS)}"
        )
    spec = importlib.util.find_spec("taxim")
    if spec is None or spec.origin is None:
        raise TactileBenchError(
            "the 'taxim' package is not installed: pip install -e '.[real]' (or pass a folder "
            f"holding {PACK_FILE} and {PARAMS_FILE})"
        )
    path = Path(spec.origin).parent / "calib" / TAXIM_SENSORS[sensor]
    if not (path / PACK_FILE).exists():
        raise TactileBenchError(f"{path}: no {PACK_FILE} in the installed taxim package")
    return path


def resolve_pack(source: str | Path) -> tuple[Path, str]:
    """(folder, sensor name) for a Taxim sensor name or a folder in the pack layout."""
    if str(source) in TAXIM_SENSORS:
        return taxim_pack_dir(str(source)), str(source)
    path = Path(source)
    if not path.is_dir():
        raise TactileBenchError(
            f"{path}: neither a Taxim sensor ({', '.join(TAXIM_SENSORS)}) nor a folder"
        )
    return path, path.name.replace("_", "-")


@dataclass
class BallPresses(Pairs):
    """N real presses of a sphere with their depth, at the size asked for.

    depth: (N, 1, H, W) gel penetration in mm; real: (N, 3, H, W) and background (3, H, W)
    in 0..255, each area-averaged from the native frame. ``centres_px`` (N, 2) x, y and
    ``radii_px`` (N,) are the annotations in native pixels; ``frame_hw`` the native size.

    Shape checks, ``subset`` and ``foreground`` are ``data.paired.Pairs``'s. A press has no
    sim image: ``sim`` is None for every set, so ``foreground("sim")`` says so.
    """

    PER_PAIR: ClassVar[tuple[str, ...]] = ("depth", "real")
    FRAMES: ClassVar[tuple[str, ...]] = ("background",)
    BACKGROUNDS: ClassVar[dict[str, str]] = {"real": "background"}
    OPTIONAL: ClassVar[frozenset[str]] = frozenset({"sim"})
    #: the base's sim images: a real press has none (not a field: constructors are unchanged)
    sim: ClassVar[None] = None

    depth: torch.Tensor
    real: torch.Tensor
    background: torch.Tensor
    centres_px: np.ndarray
    radii_px: np.ndarray
    pixmm: float
    frame_hw: tuple[int, int]
    ball_radius_mm: float
    sensor: str
    source: Path
    index: np.ndarray | None = None  # each press's position in the pack (None: 0..N-1)

    def __post_init__(self) -> None:
        if self.index is None:
            self.index = np.arange(len(self.radii_px))
        self._check_pairs(centres_px=self.centres_px, radii_px=self.radii_px, index=self.index)

    @property
    def gel_mm(self) -> tuple[float, float]:
        """(width, height) of the view in mm: native pixels times ``pixmm``."""
        return self.frame_hw[1] * self.pixmm, self.frame_hw[0] * self.pixmm

    @property
    def names(self) -> list[str]:
        return [f"press{int(i):03d}" for i in self.index]

    def halves(self) -> tuple[list[int], list[int]]:
        """(fit, held-out) indices: even presses to fit, odd presses to test on.

        Interleaving keeps both halves spread over the gel: the packs sweep the ball
        across it in order.
        """
        idx = list(range(len(self)))
        return idx[0::2], idx[1::2]

    def _subset_own(self, index: torch.Tensor | slice) -> dict[str, Any]:
        """The annotations and pack positions at ``index`` (numpy arrays, indexed as numpy)."""
        at = index if isinstance(index, slice) else index.numpy()
        return {
            "centres_px": self.centres_px[at],
            "radii_px": self.radii_px[at],
            "index": self.index[at],
        }


def _size_hw(size: int | tuple[int, int], frame_hw: tuple[int, int]) -> tuple[int, int]:
    h, w = (size, size) if isinstance(size, int) else size
    if not (2 <= h <= MAX_SIDE and 2 <= w <= MAX_SIDE):
        raise TactileBenchError(f"size: {h} x {w} must be between 2 and {MAX_SIDE} pixels")
    if h > frame_hw[0] or w > frame_hw[1]:
        raise TactileBenchError(
            f"size: {h} x {w} is larger than the native {frame_hw[0]} x {frame_hw[1]} frame"
        )
    return int(h), int(w)


def _read_pixmm(path: Path) -> float:
    try:
        params = json.loads(path.read_text())
        pixmm = float(params["sensor"]["pixmm"])
    except FileNotFoundError:
        raise TactileBenchError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TactileBenchError(f"{path}: not readable JSON ({exc})".splitlines()[0]) from None
    except (KeyError, TypeError, ValueError):
        raise TactileBenchError(f"{path}: sensor.pixmm: missing or not a number") from None
    if not (np.isfinite(pixmm) and 0 < pixmm < 1):
        raise TactileBenchError(f"{path}: sensor.pixmm: {pixmm} is not a pixel size in mm")
    return pixmm


def sphere_depth(
    centres_px: np.ndarray,
    radii_px: np.ndarray,
    frame_hw: tuple[int, int],
    pixmm: float,
    ball_radius_mm: float,
) -> torch.Tensor:
    """(N, 1, H, W) penetration (mm) of a sphere pressed until its contact has radius r.

    The cap ``sqrt(R^2 - rho^2) - sqrt(R^2 - r^2)`` where positive, at each native pixel
    centre (rho: distance from the annotated centre, in mm).
    """
    h, w = frame_hw
    ys = torch.arange(h, dtype=torch.float32)[:, None]
    xs = torch.arange(w, dtype=torch.float32)[None, :]
    out = torch.empty(len(radii_px), 1, h, w)
    big_r2 = ball_radius_mm**2
    for i, ((cx, cy), r) in enumerate(zip(centres_px, radii_px, strict=True)):
        rho2 = ((xs - float(cx)) ** 2 + (ys - float(cy)) ** 2) * pixmm**2
        floor = float(np.sqrt(big_r2 - (float(r) * pixmm) ** 2))
        out[i, 0] = (torch.sqrt((big_r2 - rho2).clamp(min=0.0)) - floor).clamp(min=0.0)
    return out


def _pool(x: torch.Tensor, hw: tuple[int, int]) -> torch.Tensor:
    """Area average down to ``hw``, as a camera pixel integrates (the paper's resize)."""
    return x if tuple(x.shape[-2:]) == hw else F.adaptive_avg_pool2d(x, hw)


def load_ball_presses(
    source: str | Path = "gelsight",
    size: int | tuple[int, int] = 64,
    ball_radius_mm: float = DEFAULT_BALL_RADIUS_MM,
) -> BallPresses:
    """Read a Taxim data pack (a sensor name or a folder) as real (depth, image) pairs.

    ``size``: an int gives S x S (the native 4:3 frame squashed, as the paper squashes the
    DIGIT's 3:4 one), a pair (H, W) any other size. Every check happens before the frames
    are resized; errors name the file and the press.
    """
    folder, sensor = resolve_pack(source)
    pack = folder / PACK_FILE
    z = load_npz(pack, ("f0", "imgs", "touch_center", "touch_radius"))
    pixmm = _read_pixmm(folder / PARAMS_FILE)
    f0, imgs = z["f0"], z["imgs"]
    centres = np.asarray(z["touch_center"], dtype=np.float64)
    radii = np.asarray(z["touch_radius"], dtype=np.float64)
    if f0.ndim != 3 or f0.shape[-1] != 3 or f0.dtype != np.uint8:
        raise TactileBenchError(
            f"{pack}: f0: expected an (H, W, 3) uint8 frame, got {f0.shape} {f0.dtype}"
        )
    if imgs.ndim != 4 or imgs.shape[1:] != f0.shape or imgs.dtype != np.uint8:
        raise TactileBenchError(
            f"{pack}: imgs: expected (N, {', '.join(map(str, f0.shape))}) uint8, got "
            f"{imgs.shape} {imgs.dtype}"
        )
    n = len(imgs)
    if n == 0:
        raise TactileBenchError(f"{pack}: imgs: no presses")
    if centres.shape != (n, 2) or radii.shape != (n,):
        raise TactileBenchError(
            f"{pack}: touch_center {centres.shape} / touch_radius {radii.shape} do not "
            f"match {n} presses"
        )
    if not (np.isfinite(ball_radius_mm) and 0 < ball_radius_mm < 100):
        raise TactileBenchError(f"ball_radius_mm: {ball_radius_mm} is not a radius in mm")
    frame_hw = (int(f0.shape[0]), int(f0.shape[1]))
    for i, ((cx, cy), r) in enumerate(zip(centres, radii, strict=True)):
        if not (0 <= cx < frame_hw[1] and 0 <= cy < frame_hw[0]):
            raise TactileBenchError(f"{pack}: press {i}: centre ({cx}, {cy}) is outside the frame")
        if not (0 < r * pixmm < ball_radius_mm):
            raise TactileBenchError(
                f"{pack}: press {i}: contact radius {r:g} px = {r * pixmm:.3f} mm does not fit "
                f"a ball of radius {ball_radius_mm:g} mm (pass a larger ball_radius_mm)"
            )
    hw = _size_hw(size, frame_hw)
    depth = sphere_depth(centres, radii, frame_hw, pixmm, ball_radius_mm)
    real = torch.from_numpy(imgs).permute(0, 3, 1, 2).float()
    background = torch.from_numpy(f0).permute(2, 0, 1).float()
    return BallPresses(
        depth=_pool(depth, hw),
        real=_pool(real, hw),
        background=_pool(background[None], hw)[0],
        centres_px=centres,
        radii_px=radii,
        pixmm=pixmm,
        frame_hw=frame_hw,
        ball_radius_mm=float(ball_radius_mm),
        sensor=sensor,
        source=folder,
    )
