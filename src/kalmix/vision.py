"""Stereo camera model: a 3-D point becomes the image feature vector ``(u_left, u_right, v)``.

The paper (Wira, Urban & Gresser 2001, section 5) watches the target with "two cameras in one
plane", so the image feature vector is three-dimensional: the horizontal coordinate in each image
and the common vertical coordinate. This module models that setup as two rectified pinhole
cameras, in pure NumPy, batched on leading axes, with no global random state.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = ["Observation", "StereoCamera"]


class Observation(NamedTuple):
    """What the cameras report for a sampled trajectory.

    Attributes
    ----------
    clean : ndarray, shape (..., T, 3)
        True features ``(u_left, u_right, v)`` in pixels at each frame.
    measured : ndarray, shape (..., T, 3)
        Noisy features, delayed by ``delay_frames``: row ``k`` holds the sample taken at frame
        ``k - delay_frames``. The first ``delay_frames`` rows are NaN, and so is every row whose
        sample was taken while the point was out of view.
    visible : ndarray of bool, shape (..., T)
        Whether the point was inside both images at frame ``k`` (aligned with ``clean``, not
        delayed).
    out_of_view_count : int
        Number of frames with ``visible`` False (summed over leading axes).
    """

    clean: np.ndarray
    measured: np.ndarray
    visible: np.ndarray
    out_of_view_count: int


def _as_last3(name: str, value, *, min_ndim: int = 1, shape_hint: str = "(..., 3)") -> np.ndarray:
    """Convert to a float array and check that its last axis has length 3."""
    array = np.asarray(value, dtype=float)
    if array.ndim < min_ndim or array.shape[-1] != 3:
        raise ValueError(f"{name}: expected shape {shape_hint}, got {array.shape}")
    return array


def _check_finite(name: str, array: np.ndarray) -> None:
    bad = np.count_nonzero(~np.isfinite(array))
    if bad:
        raise ValueError(f"{name}: expected finite values, got {bad} non-finite entries")


def _as_points(value, *, min_ndim: int = 1, shape_hint: str = "(..., 3)") -> np.ndarray:
    """Validate 3-D points in metres: shape (..., 3), finite, strictly in front of the cameras."""
    points = _as_last3("points", value, min_ndim=min_ndim, shape_hint=shape_hint)
    _check_finite("points", points)
    if points.size and np.min(points[..., 2]) <= 0.0:
        raise ValueError(
            "points: expected depth z > 0 (in front of the cameras), "
            f"got min z = {np.min(points[..., 2]):.6g}"
        )
    return points


@dataclass(frozen=True)
class StereoCamera:
    r"""Two rectified pinhole cameras in one plane (the paper's setup).

    World frame: ``x`` right, ``y`` up, ``z`` depth (forward), in metres. The left camera sits at
    ``x = -b/2`` and the right one at ``x = +b/2``, both at ``y = z = 0`` with optical axes along
    ``+z`` and identical intrinsics (focal length ``f`` in pixels, principal point at the image
    centre ``c_x = W/2``, ``c_y = H/2``). Image ``u`` grows to the right, image ``v`` grows
    downwards. A point :math:`(x, y, z)` with :math:`z > 0` has the features

    .. math::

        u_\mathrm{left} = c_x + f \frac{x + b/2}{z}, \qquad
        u_\mathrm{right} = c_x + f \frac{x - b/2}{z}, \qquad
        v = c_y - f \frac{y}{z},

    so the disparity is :math:`d = u_\mathrm{left} - u_\mathrm{right} = f b / z`.

    Parameters
    ----------
    focal_length_px : float
        Focal length ``f`` in pixels.
    baseline_m : float
        Distance ``b`` between the two optical centres, in metres.
    image_width_px, image_height_px : int
        Image size ``W`` x ``H`` in pixels (768 x 576, PAL, by default).

    Notes
    -----
    With the defaults (f = 800 px, b = 0.3 m) a target 1.2 m away moving at 1.5 m/s and sampled at
    25 Hz moves about :math:`800 \cdot 0.06 / 1.2 = 40` px per frame, the magnitude of the paper's
    fastest motion.
    """

    focal_length_px: float = 800.0
    baseline_m: float = 0.3
    image_width_px: int = 768
    image_height_px: int = 576

    def __post_init__(self) -> None:
        for name in ("focal_length_px", "baseline_m"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a finite number > 0, got {value!r}")
        for name in ("image_width_px", "image_height_px"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
                raise ValueError(f"{name}: expected an integer > 0, got {value!r}")

    @property
    def principal_point_px(self) -> tuple[float, float]:
        """Image centre :math:`(c_x, c_y) = (W/2, H/2)` in pixels."""
        return self.image_width_px / 2.0, self.image_height_px / 2.0

    # -- geometry -------------------------------------------------------------------------------

    def project(self, points) -> np.ndarray:
        r"""Project 3-D points to stereo features.

        Parameters
        ----------
        points : array_like, shape (..., 3)
            Points :math:`(x, y, z)` in metres, finite, with :math:`z > 0`.

        Returns
        -------
        ndarray, shape (..., 3)
            :math:`(u_\mathrm{left}, u_\mathrm{right}, v)` in pixels (see the class docstring).
        """
        points = _as_points(points)
        return self._project(points)

    def _project(self, points: np.ndarray) -> np.ndarray:
        f, half_b = self.focal_length_px, self.baseline_m / 2.0
        cx, cy = self.principal_point_px
        x, y, z = points[..., 0], points[..., 1], points[..., 2]
        return np.stack(
            [cx + f * (x + half_b) / z, cx + f * (x - half_b) / z, cy - f * y / z], axis=-1
        )

    def jacobian(self, points) -> np.ndarray:
        r"""Analytic Jacobian of :meth:`project` with respect to the point.

        .. math::

            \frac{\partial (u_\mathrm{left}, u_\mathrm{right}, v)}{\partial (x, y, z)} =
            \frac{f}{z}
            \begin{pmatrix}
              1 & 0 & -(x + b/2)/z \\
              1 & 0 & -(x - b/2)/z \\
              0 & -1 & y/z
            \end{pmatrix}

        Parameters
        ----------
        points : array_like, shape (..., 3)
            Points in metres, finite, :math:`z > 0`.

        Returns
        -------
        ndarray, shape (..., 3, 3)
            Row ``i`` is the gradient of feature ``i``; units pixels per metre.
        """
        points = _as_points(points)
        f, half_b = self.focal_length_px, self.baseline_m / 2.0
        x, y, z = points[..., 0], points[..., 1], points[..., 2]
        scale = f / z
        jac = np.zeros(points.shape + (3,))
        jac[..., 0, 0] = scale
        jac[..., 0, 2] = -scale * (x + half_b) / z
        jac[..., 1, 0] = scale
        jac[..., 1, 2] = -scale * (x - half_b) / z
        jac[..., 2, 1] = -scale
        jac[..., 2, 2] = scale * y / z
        return jac

    def triangulate(self, features) -> np.ndarray:
        r"""Recover 3-D points from stereo features (the inverse of :meth:`project`).

        .. math::

            z = \frac{f b}{u_\mathrm{left} - u_\mathrm{right}}, \qquad
            x = \frac{z}{f}\left(\frac{u_\mathrm{left} + u_\mathrm{right}}{2} - c_x\right), \qquad
            y = \frac{z}{f} (c_y - v).

        Parameters
        ----------
        features : array_like, shape (..., 3)
            :math:`(u_\mathrm{left}, u_\mathrm{right}, v)` in pixels, finite, with positive
            disparity :math:`u_\mathrm{left} - u_\mathrm{right} > 0`.

        Returns
        -------
        ndarray, shape (..., 3)
            Points in metres.
        """
        features = _as_last3("features", features)
        _check_finite("features", features)
        disparity = features[..., 0] - features[..., 1]
        if disparity.size and np.min(disparity) <= 0.0:
            raise ValueError(
                "features: expected positive disparity u_left - u_right > 0, "
                f"got min disparity = {np.min(disparity):.6g} px"
            )
        f = self.focal_length_px
        cx, cy = self.principal_point_px
        z = f * self.baseline_m / disparity
        x = z / f * (0.5 * (features[..., 0] + features[..., 1]) - cx)
        y = z / f * (cy - features[..., 2])
        return np.stack([x, y, z], axis=-1)

    def in_view(self, features) -> np.ndarray:
        r"""Whether features lie inside both images.

        True where all three features are finite and
        :math:`0 \le u_\mathrm{left} < W`, :math:`0 \le u_\mathrm{right} < W`,
        :math:`0 \le v < H`. NaN features (missing measurements) are out of view.

        Parameters
        ----------
        features : array_like, shape (..., 3)
            Features in pixels; non-finite values are allowed.

        Returns
        -------
        ndarray of bool, shape (...,)
        """
        features = _as_last3("features", features)
        width, height = self.image_width_px, self.image_height_px
        with np.errstate(invalid="ignore"):
            u_ok = (features[..., :2] >= 0.0) & (features[..., :2] < width)
            v_ok = (features[..., 2] >= 0.0) & (features[..., 2] < height)
        return np.all(u_ok, axis=-1) & v_ok & np.all(np.isfinite(features), axis=-1)

    def pixel_to_metre_scale(self, points) -> np.ndarray:
        r"""Approximate metres per pixel at the depth of each point, :math:`z / f`.

        A lateral displacement :math:`\delta` (metres) at depth :math:`z` moves the image by
        :math:`f \delta / z` pixels, so an image error of ``e`` pixels corresponds to about
        ``e * z / f`` metres. Used to report pixel errors in millimetres.

        Parameters
        ----------
        points : array_like, shape (..., 3)
            Points in metres, finite, :math:`z > 0`.

        Returns
        -------
        ndarray, shape (...,)
        """
        points = _as_points(points)
        return points[..., 2] / self.focal_length_px

    # -- sensing --------------------------------------------------------------------------------

    def observe(self, points, *, noise_px: float = 0.5, delay_frames: int = 0, seed) -> Observation:
        r"""Sample a trajectory with the cameras: project, add pixel noise, delay, mask.

        .. math::

            \tilde d_k = \pi(p_k) + \varepsilon_k, \quad
            \varepsilon_k \sim \mathcal N(0, \sigma^2 I_3), \qquad
            \mathrm{measured}_k = \tilde d_{k - D} \;(k \ge D), \quad \mathrm{NaN} \;(k < D),

        with :math:`\pi` = :meth:`project`, :math:`\sigma` = ``noise_px`` and :math:`D` =
        ``delay_frames``. A sample taken while the true point is outside either image is never
        kept: its row is NaN, it is counted in ``out_of_view_count``, and a ``RuntimeWarning``
        says how many frames were lost.

        Parameters
        ----------
        points : array_like, shape (T, 3) or (..., T, 3)
            Target positions in metres at each frame (time on axis -2); finite, :math:`z > 0`.
        noise_px : float, default 0.5
            Standard deviation of the additive Gaussian pixel noise, >= 0.
        delay_frames : int, default 0
            Image-acquisition delay in frames, >= 0.
        seed : int or numpy.random.Generator
            Source of the noise. Required: there is no global random state.

        Returns
        -------
        Observation
        """
        points = _as_points(points, min_ndim=2, shape_hint="(T, 3) or (..., T, 3)")
        if not (np.isscalar(noise_px) and np.isfinite(noise_px) and noise_px >= 0):
            raise ValueError(f"noise_px: expected a finite number >= 0, got {noise_px!r}")
        is_int = isinstance(delay_frames, (int, np.integer)) and not isinstance(delay_frames, bool)
        if not is_int or delay_frames < 0:
            raise ValueError(f"delay_frames: expected an integer >= 0, got {delay_frames!r}")
        rng = _as_generator(seed)

        clean = self._project(points)
        visible = self.in_view(clean)
        noisy = clean + float(noise_px) * rng.standard_normal(clean.shape)
        noisy[~visible] = np.nan

        measured = np.full_like(noisy, np.nan)
        n_frames = clean.shape[-2]
        if delay_frames < n_frames:
            measured[..., delay_frames:, :] = noisy[..., : n_frames - delay_frames, :]

        out_of_view = int(np.count_nonzero(~visible))
        if out_of_view:
            warnings.warn(
                f"observe: {out_of_view} of {visible.size} frames out of view of at least one "
                "camera; their measurements are NaN",
                RuntimeWarning,
                stacklevel=2,
            )
        return Observation(
            clean=clean, measured=measured, visible=visible, out_of_view_count=out_of_view
        )


def _as_generator(seed) -> np.random.Generator:
    """An explicit seed (int, SeedSequence) or Generator as a Generator; never the global RNG."""
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, np.random.SeedSequence) or (
        isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0
    ):
        return np.random.default_rng(seed)
    raise ValueError(f"seed: expected a non-negative int or numpy.random.Generator, got {seed!r}")
