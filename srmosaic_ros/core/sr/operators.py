"""Linear operators of the observation model (5.1), y_k = D B W_k R[x]_k + n_k, with exact adjoints.

Every operator maps torch tensors ``(B, C, H, W)`` to tensors and has ``apply`` and ``adjoint``
such that ``<A x, y> == <x, A^T y>`` up to floating-point rounding (the dot-product tests in
``test/test_sr_operators.py`` check 1e-5 relative). All work stays on the device of the inputs.

Convention (pixel grids): pixel centres at integer coordinates, ``(x, y)`` order in homographies,
x right, y down. For an integer factor ``s`` the high-resolution (HR) pixel ``(u, v)`` of a grid
sits at the low-resolution (LR) point ``((u + 0.5) / s - 0.5, (v + 0.5) / s - 0.5)``
(:func:`lr_H_hr`). The LR frame grid is decimated from an HR frame grid in the same way, so the
centre of LR pixel ``i`` lies at HR coordinate ``s * i + (s - 1) / 2``: between two HR pixels for an
even factor. The blur kernel is therefore sampled on HR offsets ``t - (k - 1) / 2`` with a kernel side
``k`` of the same parity as ``s`` and the fused D B is a ``valid`` strided convolution.

Operators:
- :class:`Warp` (W_k): bilinear resampling of the HR tile at the HR frame grid points
  (``grid_sample``); the adjoint is the exact scatter-add of the same bilinear weights.
- :class:`Blur` (B): convolution with a PSF, ``valid`` or zero-padded ``same``; adjoint is the
  correlation with the flipped kernel (``conv_transpose2d``) on the same boundary.
- :class:`Decimate` (D): periodic sampling ``x[..., ::s, ::s]``; adjoint zero-filling upsampling.
- :class:`BlurDecimate` (D B fused): strided convolution; adjoint strided transposed convolution.
- :class:`Crop`, :class:`Mask` (R): a frame's footprint: a window and a 0/1 (or weight) mask.
- :class:`Compose`: ``A = A_1 A_2 ... A_n`` (applied right to left), adjoint in reverse order.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from .modes import WARP_MODES

__all__ = [
    'LinearOperator',
    'Compose',
    'Warp',
    'WARP_MODES',
    'Blur',
    'Decimate',
    'BlurDecimate',
    'Crop',
    'Mask',
    'gaussian_psf',
    'psf_kernel_size',
    'lr_H_hr',
    'hr_H_lr',
    'dot',
]




def dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Inner product <a, b> over all elements, accumulated in float64 (a 0-dim tensor)."""
    return torch.sum(a.double() * b.double())


def lr_H_hr(factor: int) -> np.ndarray:
    """(3, 3) map from HR pixel coordinates to LR pixel coordinates: lr = (hr + 0.5) / s - 0.5."""
    s = float(factor)
    return np.array([[1.0 / s, 0.0, 0.5 / s - 0.5], [0.0, 1.0 / s, 0.5 / s - 0.5], [0.0, 0.0, 1.0]])


def hr_H_lr(factor: int) -> np.ndarray:
    """(3, 3) map from LR pixel coordinates to HR pixel coordinates: hr = s (lr + 0.5) - 0.5."""
    s = float(factor)
    return np.array([[s, 0.0, 0.5 * s - 0.5], [0.0, s, 0.5 * s - 0.5], [0.0, 0.0, 1.0]])


class LinearOperator:
    """A linear map between tensors with its exact adjoint."""

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return self.apply(x)

    def __matmul__(self, other: LinearOperator) -> Compose:
        return Compose([self, other])


class Compose(LinearOperator):
    """``A = ops[0] @ ops[1] @ ... @ ops[-1]``: apply runs right to left, adjoint left to right."""

    def __init__(self, ops: Sequence[LinearOperator]) -> None:
        flat: list[LinearOperator] = []
        for op in ops:
            flat.extend(op.ops if isinstance(op, Compose) else [op])
        self.ops = flat

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        for op in reversed(self.ops):
            x = op.apply(x)
        return x

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        for op in self.ops:
            y = op.adjoint(y)
        return y


# --------------------------------------------------------------------------------------------- W


class Warp(LinearOperator):
    """W_k: bilinear resampling of one HR image at K sets of points (one per frame).

    ``src_H_dst`` (K, 3, 3) maps pixel coordinates of the destination grid (the HR frame grid, size
    ``dst_shape = (h, w)``) to pixel coordinates of the source image (the HR tile, size
    ``src_shape = (H, W)``). ``apply`` takes ``(1, C, H, W)`` (one image shared by all frames) or
    ``(K, C, H, W)`` and returns ``(K, C, h, w)``; samples falling outside the source read zeros (the
    frame's mask removes the LR pixels they reach). ``adjoint`` takes ``(K, C, h, w)`` and returns
    ``(1, C, H, W)`` summed over the frames (``shared=True``, the R^T [W_k^T ...]_k of (5.5)) or
    ``(K, C, H, W)``: the scatter-add of the same bilinear weights, hence exact.
    """

    def __init__(self, src_H_dst: np.ndarray, src_shape: tuple[int, int], dst_shape: tuple[int, int],
                 *, device: torch.device | str = 'cpu', dtype: torch.dtype = torch.float32,
                 shared: bool = True, interpolation: str = 'bilinear') -> None:
        if interpolation not in WARP_MODES:
            msg = f'warp interpolation must be one of {WARP_MODES}, got {interpolation!r}.'
            raise ValueError(msg)
        self.interpolation = interpolation
        mats = np.asarray(src_H_dst, dtype=np.float64)
        if mats.ndim == 2:
            mats = mats[None]
        if mats.shape[1:] != (3, 3):
            msg = f'src_H_dst must be (3, 3) or (K, 3, 3), got {mats.shape}.'
            raise ValueError(msg)
        src_h, src_w = (int(v) for v in src_shape)
        if src_h < 2 or src_w < 2:
            msg = f'the source image must be at least 2x2 pixels, got {src_shape}.'
            raise ValueError(msg)
        h, w = (int(v) for v in dst_shape)
        self.src_shape = (src_h, src_w)
        self.dst_shape = (h, w)
        self.shared = shared
        self.n = mats.shape[0]
        # grid_sample(align_corners=True) coordinates: -1 and 1 are the centres of the first and last
        # source pixels. The normalisation is folded into the matrix (norm_H_src @ src_H_dst), the
        # sums of the separable row and column terms are broadcast, and the projective division
        # writes straight into the grid.
        norm_H_src = np.array([[2.0 / (src_w - 1), 0.0, -1.0], [0.0, 2.0 / (src_h - 1), -1.0], [0.0, 0.0, 1.0]])
        m = torch.as_tensor(norm_H_src @ mats, dtype=torch.float64).view(-1, 3, 3, 1, 1)
        gdt = torch.float64 if dtype == torch.float64 else torch.float32
        ys = torch.arange(h, dtype=torch.float64).view(1, h, 1)
        xs = torch.arange(w, dtype=torch.float64).view(1, 1, w)

        def plane(row: int) -> torch.Tensor:     # (K, h, w): m[row, 0] x + m[row, 1] y + m[row, 2]
            cx = (m[:, row, 0] * xs).to(device=device, dtype=gdt)
            cy = (m[:, row, 1] * ys + m[:, row, 2]).to(device=device, dtype=gdt)
            return cx + cy

        den = plane(2)
        grid = torch.empty((self.n, h, w, 2), dtype=gdt, device=device)
        torch.div(plane(0), den, out=grid[..., 0])
        torch.div(plane(1), den, out=grid[..., 1])
        self.grid = grid if gdt == dtype else grid.to(dtype)
        self._scale = ((src_w - 1) / 2.0, (src_h - 1) / 2.0)

    @property
    def points(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(K, h, w) source pixel coordinates (x, y) of every destination pixel."""
        g = self.grid
        return ((g[..., 0] + 1.0) * self._scale[0], (g[..., 1] + 1.0) * self._scale[1])

    def inside(self, tol: float = 1e-3) -> torch.Tensor:
        """(K, 1, h, w) 1 where the point has all its interpolation neighbours (2 x 2 bilinear, 4 x 4
        bicubic) inside the source, else 0.

        ``tol`` in source pixels.
        """
        g = self.grid
        if self.interpolation == 'bicubic':
            tol = tol - 1.0
        tx, ty = tol / self._scale[0], tol / self._scale[1]
        ok = (g[..., 0].abs() <= 1.0 + tx) & (g[..., 1].abs() <= 1.0 + ty)
        return ok[:, None].to(g.dtype)

    def displace(self, offset: torch.Tensor) -> Warp:
        """Move every sampling point by ``offset`` (K, h, w, 2) source pixels, (x, y) order, in place.

        A per-pixel refinement of the homography (core/sr/dense_flow.py): the operator stays a bilinear
        sampling at fixed points, so the adjoint (the scatter-add of the same weights) stays exact.
        """
        if tuple(offset.shape) != (*self.grid.shape[:3], 2):
            msg = f'a warp offset is (K, h, w, 2) = {(*self.grid.shape[:3], 2)}, got {tuple(offset.shape)}.'
            raise ValueError(msg)
        scale = self.grid.new_tensor([1.0 / self._scale[0], 1.0 / self._scale[1]])
        self.grid.add_(offset.to(self.grid.dtype) * scale)
        return self

    def _src(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[0] == 1 and self.n != 1:
            return x.expand(self.n, *x.shape[1:])
        if x.shape[0] != self.n:
            msg = f'Warp over {self.n} frames got a batch of {x.shape[0]} images; give 1 or {self.n}.'
            raise ValueError(msg)
        return x

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        grid = self.grid if self.grid.dtype == x.dtype else self.grid.to(x.dtype)
        return F.grid_sample(self._src(x), grid, mode=self.interpolation, padding_mode='zeros', align_corners=True)

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        grid = self.grid if self.grid.dtype == y.dtype else self.grid.to(y.dtype)
        src = torch.empty((1, 1, 1, 1), dtype=y.dtype, device=y.device).expand(
            self.n, y.shape[1], *self.src_shape)
        # The input gradient of grid_sample is the scatter-add of the bilinear weights: W^T y.
        grad_src, _ = torch.ops.aten.grid_sampler_2d_backward(
            y.contiguous(), src, grid, WARP_MODES.index(self.interpolation) * 2, 0, True, [True, False])
        return grad_src.sum(dim=0, keepdim=True) if self.shared else grad_src


# --------------------------------------------------------------------------------------------- B


def psf_kernel_size(sigma_hr: float, factor: int = 1, *, truncate: float = 3.0) -> int:
    """Side of a Gaussian kernel of std ``sigma_hr`` (HR pixels) truncated at ``truncate`` sigma.

    The side has the parity of ``factor`` so that the kernel is centred on an LR pixel centre
    (between HR pixels for an even factor).
    """
    k = 2 * math.ceil(truncate * max(sigma_hr, 1e-6)) + 1
    if (k - factor) % 2:
        k += 1
    return max(k, factor % 2 or 2)


def gaussian_psf(sigma_hr: float, factor: int = 1, *, size: int | None = None,
                 truncate: float = 3.0, dtype: torch.dtype = torch.float32,
                 device: torch.device | str = 'cpu') -> torch.Tensor:
    """(k, k) Gaussian PSF of std ``sigma_hr`` HR pixels sampled at offsets ``t - (k - 1) / 2``, sum 1.

    With ``sigma_hr == 0`` the PSF is the identity (odd k) or the mean of the central 2x2 HR pixels
    (even k). ``size`` defaults to :func:`psf_kernel_size`; it must have the parity of ``factor``.
    """
    k = psf_kernel_size(sigma_hr, factor, truncate=truncate) if size is None else int(size)
    if (k - factor) % 2:
        msg = f'PSF side {k} and factor {factor} differ in parity; the PSF would be off-centre by half a pixel.'
        raise ValueError(msg)
    d = torch.arange(k, dtype=torch.float64) - (k - 1) / 2.0
    if sigma_hr > 0:
        g = torch.exp(-0.5 * (d / sigma_hr) ** 2)
    else:
        g = (d.abs() <= 0.5).double()
    g = g / g.sum()
    return torch.outer(g, g).to(dtype=dtype, device=device)


def _channel_weight(kernel: torch.Tensor, channels: int, dtype: torch.dtype,
                    device: torch.device) -> torch.Tensor:
    """(C, 1, kh, kw) depthwise weight that makes conv2d a true convolution with ``kernel``."""
    k = torch.flip(kernel, dims=(-2, -1)).to(dtype=dtype, device=device)
    return k[None, None].expand(channels, 1, *k.shape).contiguous()


class _Conv:
    """Depthwise (per channel) convolution weights cached per (C, dtype, device)."""

    def __init__(self, kernel: torch.Tensor) -> None:
        kernel = torch.as_tensor(kernel)
        if kernel.ndim != 2:
            msg = f'a PSF kernel is a 2-D tensor (kh, kw), got shape {tuple(kernel.shape)}.'
            raise ValueError(msg)
        self._cache: dict[tuple[int, torch.dtype, torch.device], torch.Tensor] = {}
        self._sep_cache: dict[tuple[int, torch.dtype, torch.device], tuple[torch.Tensor, torch.Tensor]] = {}
        # A rank-1 kernel (every Gaussian) allows separable passes; it is then stored as the exact
        # outer product of its factors so that 2-D and separable passes are the same operator.
        u, s, vh = torch.linalg.svd(kernel.double())
        self.separable = bool(s.numel() == 1 or s[1] <= 1e-6 * s[0])
        self._col = u[:, 0] * torch.sqrt(s[0])
        self._row = vh[0] * torch.sqrt(s[0])
        self.kernel = torch.outer(self._col, self._row).to(kernel.dtype) if self.separable else kernel

    def weight(self, channels: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
        key = (channels, dtype, device)
        if key not in self._cache:
            self._cache[key] = _channel_weight(self.kernel, channels, dtype, device)
        return self._cache[key]

    def separable_weights(self, channels: int, dtype: torch.dtype,
                          device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
        key = (channels, dtype, device)
        if key not in self._sep_cache:
            col = torch.flip(self._col, (0,)).to(dtype=dtype, device=device)
            row = torch.flip(self._row, (0,)).to(dtype=dtype, device=device)
            self._sep_cache[key] = (col.view(1, 1, -1, 1).expand(channels, 1, -1, 1).contiguous(),
                                    row.view(1, 1, 1, -1).expand(channels, 1, 1, -1).contiguous())
        return self._sep_cache[key]


class Blur(LinearOperator):
    """B: convolution with a PSF ``kernel`` (kh, kw), each channel alone.

    ``mode='valid'``: output ``(H - kh + 1, W - kw + 1)``, only where the kernel fits; the adjoint is
    the full correlation with the flipped kernel (zero outside), so it is exact.
    ``mode='same'``: zero padding of ``(kh - 1) // 2`` before and ``kh // 2`` after (same for the
    width); output ``(H, W)``; the adjoint crops the full correlation the same way.
    """

    def __init__(self, kernel: torch.Tensor, *, mode: str = 'valid') -> None:
        if mode not in ('valid', 'same'):
            msg = f"Blur mode must be 'valid' or 'same', got {mode!r}."
            raise ValueError(msg)
        self.conv = _Conv(kernel)
        self.mode = mode
        kh, kw = self.conv.kernel.shape
        self.pad = ((kw - 1) // 2, kw // 2, (kh - 1) // 2, kh // 2)  # F.pad order: left right top bottom

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        if self.mode == 'same':
            x = F.pad(x, self.pad)
        return F.conv2d(x, self.conv.weight(x.shape[1], x.dtype, x.device), groups=x.shape[1])

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        z = F.conv_transpose2d(y, self.conv.weight(y.shape[1], y.dtype, y.device), groups=y.shape[1])
        if self.mode == 'same':
            left, right, top, bottom = self.pad
            z = z[..., top:z.shape[-2] - bottom, left:z.shape[-1] - right]
        return z


# --------------------------------------------------------------------------------------------- D


class Decimate(LinearOperator):
    """D: periodic sampling ``x[..., ::s, ::s]`` of an ``(H, W)`` grid; D^T: zero-filling upsampling.

    ``shape`` is the (H, W) of the fine grid (needed by the adjoint).
    """

    def __init__(self, factor: int, shape: tuple[int, int]) -> None:
        if int(factor) < 1:
            msg = f'the decimation factor must be a positive integer, got {factor}.'
            raise ValueError(msg)
        self.factor = int(factor)
        self.shape = (int(shape[0]), int(shape[1]))

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        s = self.factor
        return x[..., ::s, ::s]

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        s = self.factor
        z = torch.zeros((*y.shape[:-2], *self.shape), dtype=y.dtype, device=y.device)
        z[..., ::s, ::s] = y
        return z


class BlurDecimate(LinearOperator):
    """D B fused: ``valid`` convolution with the PSF evaluated only at every s-th HR position.

    Input ``(B, C, s (h - 1) + kh, s (w - 1) + kw)`` (the HR frame grid with the PSF margin), output
    ``(B, C, h, w)``; equal to ``Decimate(s) @ Blur(kernel, mode='valid')``. A rank-1 kernel (every
    Gaussian) runs as two 1-D passes of strided slices (a column pass, then a row pass), each a
    handful of multiply-adds over the image, and the adjoint scatters through the same slices in
    reverse order, so it is exact; other kernels, and every kernel on a GPU (``impl='auto'``), use a
    strided convolution and its transposed convolution.
    """

    def __init__(self, kernel: torch.Tensor, factor: int, *, impl: str = 'auto') -> None:
        if impl not in ('auto', 'conv', 'slices'):
            msg = f"impl must be 'auto', 'conv' or 'slices', got {impl!r}."
            raise ValueError(msg)
        self.conv = _Conv(kernel)
        self.factor = int(factor)
        self.impl = impl
        self._taps: dict[torch.dtype, tuple[list[float], list[float]]] = {}

    def _slices(self, x: torch.Tensor) -> bool:
        """Strided slices for a separable kernel on the CPU ('auto'); cuDNN convolutions on a GPU,
        where one kernel launch beats sixteen."""
        if not self.conv.separable or self.impl == 'conv':
            return False
        return self.impl == 'slices' or not x.is_cuda

    def hr_shape(self, lr_shape: tuple[int, int]) -> tuple[int, int]:
        kh, kw = self.conv.kernel.shape
        s = self.factor
        return (s * (lr_shape[0] - 1) + kh, s * (lr_shape[1] - 1) + kw)

    def _weights(self, dtype: torch.dtype) -> tuple[list[float], list[float]]:
        """Correlation taps (the flipped factors) as Python floats rounded to ``dtype``."""
        if dtype not in self._taps:
            col = torch.flip(self.conv._col, (0,)).to(dtype)
            row = torch.flip(self.conv._row, (0,)).to(dtype)
            self._taps[dtype] = ([float(v) for v in col], [float(v) for v in row])
        return self._taps[dtype]

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        c = x.shape[1]
        s = self.factor
        if not self._slices(x):
            return F.conv2d(x, self.conv.weight(c, x.dtype, x.device), stride=s, groups=c)
        col, row = self._weights(x.dtype)
        h = (x.shape[-2] - len(col)) // s + 1
        w = (x.shape[-1] - len(row)) // s + 1
        z = x[..., :, 0:s * (w - 1) + 1:s] * row[0]
        for t in range(1, len(row)):
            z.add_(x[..., :, t:t + s * (w - 1) + 1:s], alpha=row[t])
        out = z[..., 0:s * (h - 1) + 1:s, :] * col[0]
        for t in range(1, len(col)):
            out.add_(z[..., t:t + s * (h - 1) + 1:s, :], alpha=col[t])
        return out

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        c = y.shape[1]
        s = self.factor
        if not self._slices(y):
            return F.conv_transpose2d(y, self.conv.weight(c, y.dtype, y.device), stride=s, groups=c)
        col, row = self._weights(y.dtype)
        h, w = y.shape[-2:]
        hg, wg = self.hr_shape((h, w))
        z = y.new_zeros((*y.shape[:-2], hg, w))
        for t in range(len(col)):
            z[..., t:t + s * (h - 1) + 1:s, :].add_(y, alpha=col[t])
        out = y.new_zeros((*y.shape[:-2], hg, wg))
        for t in range(len(row)):
            out[..., :, t:t + s * (w - 1) + 1:s].add_(z, alpha=row[t])
        return out


# --------------------------------------------------------------------------------------------- R


class Crop(LinearOperator):
    """R as a window: ``x[..., y0:y0 + h, x0:x0 + w]`` of an ``(H, W)`` grid; adjoint zero-pads back."""

    def __init__(self, y0: int, x0: int, size: tuple[int, int], shape: tuple[int, int]) -> None:
        self.y0, self.x0 = int(y0), int(x0)
        self.size = (int(size[0]), int(size[1]))
        self.shape = (int(shape[0]), int(shape[1]))
        if (self.y0 < 0 or self.x0 < 0 or self.y0 + self.size[0] > self.shape[0]
                or self.x0 + self.size[1] > self.shape[1]):
            msg = f'crop window {self.size} at ({self.y0}, {self.x0}) leaves the {self.shape} grid.'
            raise ValueError(msg)

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        return x[..., self.y0:self.y0 + self.size[0], self.x0:self.x0 + self.size[1]]

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        z = torch.zeros((*y.shape[:-2], *self.shape), dtype=y.dtype, device=y.device)
        z[..., self.y0:self.y0 + self.size[0], self.x0:self.x0 + self.size[1]] = y
        return z


class Mask(LinearOperator):
    """R as a footprint mask: elementwise product with ``mask`` (broadcast); self-adjoint."""

    def __init__(self, mask: torch.Tensor) -> None:
        self.mask = mask

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.mask

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        return y * self.mask
