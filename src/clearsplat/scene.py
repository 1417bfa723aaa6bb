"""Gaussians, cameras, images and the view association of one prediction.

Shapes and conventions are documented in ``docs/conventions.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import numpy as np

from .cameras import Camera
from .errors import ClearsplatError

__all__ = ["Gaussians", "Scene", "RenderSettings", "SH_C0", "SH_COUNTS", "SHARED",
           "rgb_to_sh_dc", "sh_dc_to_rgb"]

#: Zeroth-order real spherical-harmonic constant: colour = SH_C0 * f_dc + 0.5.
SH_C0 = 0.28209479177387814
#: Coefficients per colour channel of SH degrees 0 to 4.
SH_COUNTS = (1, 4, 9, 16, 25)
#: ``Scene.view_id`` of a Gaussian that no single view made: fused static content that
#: several views see alike (:func:`clearsplat.adapters.associate_fused`).
SHARED = -1


def pixel_limits(cameras, view_id: np.ndarray) -> np.ndarray:
    """(N,) int64: per Gaussian, the pixel count of its view's image, which its ``pixel_id``
    must stay below; 0 for a shared one (view id -1), which has no pixel."""
    sizes = np.array([0] + [c.width * c.height for c in cameras], dtype=np.int64)
    return sizes[np.asarray(view_id) + 1]


def rgb_to_sh_dc(rgb: np.ndarray) -> np.ndarray:
    """DC coefficients (..., 3) that render as the view-independent colour ``rgb``."""
    return ((np.asarray(rgb, dtype=np.float32) - 0.5) / SH_C0).astype(np.float32)


def sh_dc_to_rgb(dc: np.ndarray) -> np.ndarray:
    """Colour of DC coefficients before clamping: ``SH_C0 * dc + 0.5``."""
    return (SH_C0 * np.asarray(dc, dtype=np.float32) + 0.5).astype(np.float32)


@dataclass(frozen=True)
class RenderSettings:
    """How a scene's Gaussians are rasterized: the settings of the renderer they were made for.

    The defaults are the original 3DGS rasterizer (what pixelSplat, MVSplat, DepthSplat and
    NoPoSplat render with). Stored in ``cameras.json`` as the top-level ``"render"`` object;
    every field is described in ``docs/conventions.md`` ("Render settings").

    Attributes
    ----------
    antialiased : bool, default False
        gsplat's ``rasterize_mode="antialiased"``: each Gaussian's opacity is multiplied by
        ``sqrt(det(Sigma2D) / det(Sigma2D + eps2d I))`` so the blur below does not spread a
        sub-pixel Gaussian's energy. False: the classic 3DGS rasterizer.
    eps2d : float, default 0.3
        Added to the diagonal of every projected 2D covariance, in pixels squared.
    radius_clip : float, default 0.0
        Gaussians whose pixel radius is at most this are skipped (gsplat's ``radius_clip``).
    sh_degree : int or None, default None
        Highest SH degree the renderer evaluates (0-4); None: all the Gaussians carry. Higher
        bands than this are ignored.
    """

    antialiased: bool = False
    eps2d: float = 0.3
    radius_clip: float = 0.0
    sh_degree: int | None = None

    def __post_init__(self):
        self.validate()

    @property
    def is_classic(self) -> bool:
        """True for the original 3DGS rasterizer (the defaults)."""
        return self == RenderSettings()

    def validate(self, *, path=None, field: str = "render") -> None:
        """Raise :class:`ClearsplatError` naming the field if a value is out of range."""
        if not isinstance(self.antialiased, (bool, np.bool_)):
            raise ClearsplatError(f"expected true or false, got {self.antialiased!r}",
                                  path=path, field=f"{field}.antialiased")
        for name in ("eps2d", "radius_clip"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) \
                    or not np.isfinite(v) or v < 0:
                raise ClearsplatError(f"expected a finite number >= 0, got {v!r}",
                                      path=path, field=f"{field}.{name}")
        d = self.sh_degree
        if d is not None and (isinstance(d, bool) or not isinstance(d, (int, np.integer))
                              or not 0 <= d <= 4):
            raise ClearsplatError(f"expected null or an integer 0 to 4, got {d!r}",
                                  path=path, field=f"{field}.sh_degree")

    def to_json(self) -> dict:
        """The ``"render"`` object of ``cameras.json`` (only the fields that differ from the
        defaults)."""
        out = {}
        for name, default in (("antialiased", False), ("eps2d", 0.3), ("radius_clip", 0.0),
                              ("sh_degree", None)):
            v = getattr(self, name)
            if v != default:
                out[name] = bool(v) if name == "antialiased" else (
                    int(v) if name == "sh_degree" else float(v))
        return out

    @classmethod
    def from_json(cls, obj, *, path=None) -> "RenderSettings":
        """Settings from a ``"render"`` object (missing fields take the defaults)."""
        if obj is None:
            return cls()
        if not isinstance(obj, dict):
            raise ClearsplatError(f"expected an object, got {type(obj).__name__}", path=path,
                                  field="render")
        known = {"antialiased", "eps2d", "radius_clip", "sh_degree"}
        for k in obj:
            if k not in known:
                raise ClearsplatError(f"unknown render setting {k!r} (known: "
                                      f"{', '.join(sorted(known))})", path=path,
                                      field=f"render.{k}")
        tmp = object.__new__(cls)             # validate with the path before constructing
        for name, default in (("antialiased", False), ("eps2d", 0.3), ("radius_clip", 0.0),
                              ("sh_degree", None)):
            object.__setattr__(tmp, name, obj.get(name, default))
        tmp.validate(path=path)
        return cls(**{k: getattr(tmp, k) for k in known})


@dataclass(eq=False)
class Gaussians:
    """A set of N 3D Gaussians (float32 arrays, C-contiguous).

    Attributes
    ----------
    means : (N, 3) float32
        Centres in world coordinates.
    scales : (N, 3) float32
        Standard deviations along the local axes (linear, positive).
    quats : (N, 4) float32
        Rotations as quaternions ``w, x, y, z``; normalised when used.
    opacities : (N,) float32
        Opacity in [0, 1] (not the logit stored on disk).
    sh : (N, K, 3) float32
        Spherical-harmonic colour coefficients, K in {1, 4, 9, 16, 25} (degree 0 to 4);
        ``sh[:, 0]`` is the DC term, colour = SH_C0 * dc + 0.5 + higher bands.
    extra : dict of str to (N,) arrays
        Further per-Gaussian properties (read from a PLY and written back).
    """

    means: np.ndarray
    scales: np.ndarray
    quats: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        self.means = _f32(self.means)
        self.scales = _f32(self.scales)
        self.quats = _f32(self.quats)
        self.opacities = _f32(self.opacities)
        self.sh = _f32(self.sh)
        if self.sh.ndim == 2 and self.sh.shape[1:] == (3,):
            self.sh = self.sh[:, None, :].copy()
        self.extra = {str(k): np.ascontiguousarray(v) for k, v in dict(self.extra).items()}

    def __len__(self) -> int:
        return int(self.means.shape[0])

    def __repr__(self) -> str:
        extra = f", extra {sorted(self.extra)}" if self.extra else ""
        return f"Gaussians({len(self):,}, SH degree {self.sh_degree}{extra})"

    @property
    def sh_degree(self) -> int:
        """Spherical-harmonic degree: 0 for K=1, 1 for 4, 2 for 9, 3 for 16, 4 for 25."""
        return int(round(np.sqrt(self.sh.shape[1]))) - 1

    def subset(self, index) -> "Gaussians":
        """A new set holding ``index`` (bool mask or integer indices)."""
        return Gaussians(self.means[index], self.scales[index], self.quats[index],
                         self.opacities[index], self.sh[index],
                         {k: v[index] for k, v in self.extra.items()})

    def validate(self, *, path=None) -> None:
        """Raise :class:`ClearsplatError` naming the field if anything is malformed."""
        n = len(self)
        expect = {"means": (n, 3), "scales": (n, 3), "quats": (n, 4), "opacities": (n,)}
        for name, shape in expect.items():
            arr = getattr(self, name)
            if arr.shape != shape:
                raise ClearsplatError(f"expected shape {shape}, got {arr.shape}",
                                      path=path, field=name)
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3 \
                or self.sh.shape[1] not in SH_COUNTS:
            raise ClearsplatError(f"expected shape ({n}, K, 3) with K in 1, 4, 9, 16, 25, "
                                  f"got {self.sh.shape}", path=path, field="sh")
        for name in ("means", "scales", "quats", "opacities", "sh"):
            arr = getattr(self, name)
            # A finite sum proves every value finite (one pass, nothing allocated); an
            # infinite or NaN one (or an overflow) asks value by value.
            with np.errstate(over="ignore", invalid="ignore"):
                if np.isfinite(arr.sum(dtype=np.float64)):
                    continue
            bad = ~np.isfinite(arr)
            if bad.any():
                i = int(np.argwhere(bad)[0][0])
                raise ClearsplatError(f"non-finite value (first at Gaussian {i})",
                                      path=path, field=name)
        if n and not self.scales.min() > 0:
            i = int(np.argwhere(~(self.scales > 0).all(axis=1))[0][0])
            raise ClearsplatError(f"scales must be positive (first bad Gaussian {i})",
                                  path=path, field="scales")
        if n:
            qn = np.sqrt(np.einsum("ij,ij->i", self.quats, self.quats, dtype=np.float64))
            if not qn.min() > 1e-12:
                i = int(np.argmin(qn))
                raise ClearsplatError(f"zero quaternion (first at Gaussian {i})",
                                      path=path, field="quats")
            if not (self.opacities.min() >= 0 and self.opacities.max() <= 1):
                i = int(np.argwhere((self.opacities < 0) | (self.opacities > 1))[0][0])
                raise ClearsplatError(f"opacity outside [0, 1] (first at Gaussian {i})",
                                      path=path, field="opacities")
        for k, v in self.extra.items():
            if v.shape[:1] != (n,):
                raise ClearsplatError(f"expected {n} values, got shape {v.shape}",
                                      path=path, field=k)


@dataclass(eq=False)
class Scene:
    """One feed-forward prediction: Gaussians, their input views, and those views.

    Attributes
    ----------
    gaussians : Gaussians
        The N predicted Gaussians.
    view_id : (N,) int32
        Index of the input view whose prediction produced each Gaussian, or :data:`SHARED`
        (-1) for one that several views made together and see alike (fused static content):
        the filter keeps it in every view's render without that view's own Gaussians and maps
        no region to it. A shared Gaussian has ``pixel_id`` -1.
    pixel_id : (N,) int64
        ``row * width + col`` in that view's image, or -1 where the model is not
        pixel-aligned. Several Gaussians may share a pixel.
    cameras : list of Camera
        The input cameras, in view-id order.
    images : list of (H, W, 3) float32 arrays, or None
        The input images, RGB in [0, 1], one per camera.
    render_settings : RenderSettings
        How the model that predicted the Gaussians renders them (classic 3DGS by default);
        :func:`clearsplat.render` and the filter render the scene this way.
    """

    gaussians: Gaussians
    view_id: np.ndarray
    pixel_id: np.ndarray | None
    cameras: list
    images: list | None = None
    render_settings: RenderSettings = field(default_factory=RenderSettings)

    def __post_init__(self):
        n = len(self.gaussians)
        self.view_id = np.ascontiguousarray(self.view_id, dtype=np.int32)
        if self.pixel_id is None:
            self.pixel_id = np.full(n, -1, dtype=np.int64)
        self.pixel_id = np.ascontiguousarray(self.pixel_id, dtype=np.int64)
        self.cameras = list(self.cameras)
        if self.images is not None:
            self.images = [np.ascontiguousarray(im, dtype=np.float32) for im in self.images]
        if self.render_settings is None:
            self.render_settings = RenderSettings()

    # -- properties --------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.gaussians)

    def __repr__(self) -> str:
        sizes = sorted({(c.width, c.height) for c in self.cameras})
        size = ", ".join(f"{w}x{h}" for w, h in sizes) or "no cameras"
        aligned = "pixel-aligned" if self.is_pixel_aligned else "not pixel-aligned"
        images = "with images" if self.images is not None else "without images"
        return (f"Scene({len(self):,} Gaussians, SH degree {self.gaussians.sh_degree}; "
                f"{self.num_views} views of {size}; {aligned}; {images})")

    @property
    def num_views(self) -> int:
        return len(self.cameras)

    @property
    def is_pixel_aligned(self) -> bool:
        """True when every Gaussian carries a pixel index."""
        return bool(len(self) and (self.pixel_id >= 0).all())

    def view_mask(self, view: int) -> np.ndarray:
        """Boolean mask (N,) of the Gaussians predicted from input ``view``."""
        return self.view_id == view

    def with_opacities(self, opacities: np.ndarray) -> "Scene":
        """A copy that shares everything except the opacities."""
        g = replace(self.gaussians, opacities=np.asarray(opacities, dtype=np.float32))
        return replace(self, gaussians=g)

    def subset(self, index) -> "Scene":
        """A scene holding the Gaussians in ``index`` (bool mask or indices), same views."""
        return Scene(self.gaussians.subset(index), self.view_id[index], self.pixel_id[index],
                     self.cameras, self.images, self.render_settings)

    # -- checks ------------------------------------------------------------------------------
    def validate(self, *, path=None) -> None:
        """Raise :class:`ClearsplatError` naming the field if anything is inconsistent."""
        self.gaussians.validate(path=path)
        if not isinstance(self.render_settings, RenderSettings):
            raise ClearsplatError(f"expected RenderSettings, got "
                                  f"{type(self.render_settings).__name__}", path=path,
                                  field="render")
        self.render_settings.validate(path=path)
        n, v = len(self), self.num_views
        if self.view_id.shape != (n,):
            raise ClearsplatError(f"expected {n} values, got shape {self.view_id.shape}",
                                  path=path, field="view_id")
        if self.pixel_id.shape != (n,):
            raise ClearsplatError(f"expected {n} values, got shape {self.pixel_id.shape}",
                                  path=path, field="pixel_id")
        if v == 0:
            raise ClearsplatError("the scene has no cameras", path=path, field="cameras")
        for i, cam in enumerate(self.cameras):
            if not isinstance(cam, Camera):
                raise ClearsplatError(f"expected a Camera, got {type(cam).__name__}",
                                      path=path, field=f"cameras[{i}]")
        if n:
            bad = (self.view_id < SHARED) | (self.view_id >= v)
            if bad.any():
                i = int(np.argmax(bad))
                raise ClearsplatError(f"view id {int(self.view_id[i])} out of range 0..{v - 1} "
                                      f"or {SHARED} (Gaussian {i})", path=path, field="view_id")
            limit = pixel_limits(self.cameras, self.view_id)
            bad = (self.pixel_id < -1) | (self.pixel_id >= limit)
            if bad.any():
                i = int(np.argmax(bad))
                shared = " (shared: no pixel)" if self.view_id[i] == SHARED else ""
                raise ClearsplatError(f"pixel id {int(self.pixel_id[i])} out of range for view "
                                      f"{int(self.view_id[i])}{shared} (Gaussian {i})",
                                      path=path, field="pixel_id")
        if self.images is not None:
            if len(self.images) != v:
                raise ClearsplatError(f"{len(self.images)} images for {v} cameras",
                                      path=path, field="images")
            for i, (im, cam) in enumerate(zip(self.images, self.cameras)):
                if im.shape != (cam.height, cam.width, 3):
                    raise ClearsplatError(f"image {i} has shape {im.shape}, camera expects "
                                          f"{(cam.height, cam.width, 3)}",
                                          path=path, field=f"images[{i}]")
                if not np.all(np.isfinite(im)):
                    raise ClearsplatError(f"image {i} has non-finite values",
                                          path=path, field=f"images[{i}]")

    # -- files -------------------------------------------------------------------------------
    def save(self, path, *, overwrite: bool = False) -> None:
        """Write a scene bundle (``cameras.json``, ``images/``, ``gaussians.ply``).

        See :func:`clearsplat.io.save_scene`.
        """
        if _bundle_writer is None:       # only when clearsplat.io was never imported
            raise ClearsplatError("no bundle writer: import clearsplat.io first", field="path")
        _bundle_writer(self, path, overwrite=overwrite)


#: ``clearsplat.io.save_scene``, set by :mod:`clearsplat.io.bundle` when it is imported (which
#: ``import clearsplat`` does): io sits above this module, so it is never imported from here.
_bundle_writer = None


def register_bundle_writer(writer) -> None:
    """Set the function :meth:`Scene.save` calls, ``writer(scene, path, overwrite=...)``."""
    global _bundle_writer
    _bundle_writer = writer


def _f32(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)

