"""Describing a frame with fixed tensor shapes, and replaying that work as one CUDA graph on a GPU.

On a GPU a 640x480 frame is launch-bound: describe dispatches some 800 tensor operations of a few
microseconds of GPU work each, and the two data-dependent selections (``nonzero`` of the
scale-space maxima and of the template blocks) each wait for the GPU to drain. With fixed shapes
(``topk`` in their place: detect's ``static_k``, make_template's ``static``) the whole of describe
is one sequence of kernels with no host synchronisation, which a CUDA graph records once per frame
size and replays with one launch (torch.cuda.CUDAGraph); one synchronisation at the end reads how
many candidates are real and trims the outputs to what the data-dependent path gives.

:class:`StaticDescriber` does this for TorchRegistrar (``TorchRegistrarOptions.static_shapes``, on
by default on a GPU; the CUDA graphs with ``cuda_graphs``): ``run(gray)`` returns the pyramid, the candidates, the first keypoints and
the templates of a (1, 1, H, W) luminance tensor. On the CPU (tests, or static_shapes forced on)
the same fixed-shape operations run eagerly: the outputs equal those of the data-dependent path up
to the order of exactly tied responses and the ties at the template cut. A CUDA graph that cannot
be captured (an operation the capture refuses) is reported once and the eager fixed-shape path is
used for that frame size.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import torch

from .torch_features import (
    FeatureOptions,
    KeypointSet,
    ScaleSpaceCandidates,
    build_pyramid,
    describe_candidates,
    detect,
)
from .torch_refine import PhotometricOptions, PhotometricTemplate, make_template

__all__ = ['DescribeOutput', 'StaticDescriber']

_LOG = logging.getLogger(__name__)
_WARMUP_RUNS = 2  # eager runs on a side stream before the capture (lazy constants, cuDNN plans, allocator)


@dataclass
class DescribeOutput:
    """What describe computes for a frame (see TorchFeatures)."""

    pyramid: list[torch.Tensor]
    candidates: ScaleSpaceCandidates
    keypoints: KeypointSet
    templates: list[PhotometricTemplate]


class _Layout:
    """The fixed-shape describe as a function of one tensor to a flat list of tensors, and back:
    the Python side of its outputs (levels, sizes, matrices) is recorded at the first call."""

    def __init__(self, levels: int, pyramid_sigma: float, features: FeatureOptions,
                 photometric: PhotometricOptions | None, static_k: int) -> None:
        self.levels, self.sigma = levels, pyramid_sigma
        self.features, self.photometric, self.static_k = features, photometric, static_k
        self.skeleton: DescribeOutput | None = None

    def tensors(self, gray: torch.Tensor) -> list[torch.Tensor]:
        _, _, _, w = gray.shape
        pyr = build_pyramid(gray, self.levels, sigma=self.sigma)
        lvl = self.features.level_for(w)
        cands = detect(pyr[lvl], lvl, self.features, static_k=self.static_k)
        kps = describe_candidates(cands, 0, self.features.max_keypoints)
        templates = []
        ph = self.photometric
        if ph is not None:
            templates = [make_template(pyr[level], level, points=points, static=True)
                         for level, points in zip(ph.levels, ph.points, strict=True)]
        self.skeleton = DescribeOutput(pyr, cands, kps, templates)
        out = [*pyr, cands.xy, cands.sub_level, cands.octave, cands.response, cands.tall, cands.count,
               kps.xy, kps.scale, kps.angle, kps.response, kps.descriptors]
        for t in templates:
            out += [t.xn, t.values, t.sd]
        return out

    def assemble(self, flat: list[torch.Tensor], skeleton: DescribeOutput | None = None) -> DescribeOutput:
        """The outputs, trimmed to the real candidates (one host synchronisation: their count);
        skeleton: the Python side of the outputs (default: of the last call of tensors)."""
        sk = skeleton or self.skeleton
        assert sk is not None
        n_pyr = len(sk.pyramid)
        pyr = flat[:n_pyr]
        xy, sub, octave, resp, tall, count, kxy, kscale, kangle, kresp, kdesc = flat[n_pyr:n_pyr + 11]
        n = int(count)
        k = min(n, kxy.shape[0])
        c = sk.candidates
        cands = ScaleSpaceCandidates(c.level, xy[:n], sub[:n], octave[:n], resp[:n], tall, c.row0, c.size, c.sigma0,
                                     c.scales_per_octave)
        kps = KeypointSet(kxy[:k], kscale[:k], kangle[:k], kresp[:k], kdesc[:k])
        rest = flat[n_pyr + 11:]
        templates = [replace(t, xn=rest[3 * i], values=rest[3 * i + 1], sd=rest[3 * i + 2])
                     for i, t in enumerate(sk.templates)]
        return DescribeOutput(list(pyr), cands, kps, templates)


class _Graph:
    """One frame size's describe recorded as a CUDA graph: copy the frame in, replay, clone out."""

    def __init__(self, layout: _Layout, example: torch.Tensor) -> None:
        fn = layout.tensors
        self.static_in = example.clone()
        side = torch.cuda.Stream(device=example.device)
        side.wait_stream(torch.cuda.current_stream(example.device))
        with torch.cuda.stream(side):
            for _ in range(_WARMUP_RUNS):
                fn(self.static_in)
        torch.cuda.current_stream(example.device).wait_stream(side)
        self.graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(self.graph):
            self.static_out = fn(self.static_in)
        self.skeleton = layout.skeleton  # this frame size's levels, sizes and template matrices

    def __call__(self, gray: torch.Tensor) -> list[torch.Tensor]:
        self.static_in.copy_(gray)
        self.graph.replay()
        # the next replay overwrites the static outputs; the previous frame's features must live on
        return [t.clone() for t in self.static_out]


class StaticDescriber:
    """describe with fixed shapes, replayed as a CUDA graph per frame size on a GPU (module docstring).

    static_k: candidates kept per octave at most (the strongest; a 640x480 frame has 400 to 550).
    cuda_graphs: record and replay CUDA graphs on a CUDA device (else run the operations eagerly).
    """

    def __init__(self, levels: int, pyramid_sigma: float, features: FeatureOptions,
                 photometric: PhotometricOptions | None, *, static_k: int = 2048, cuda_graphs: bool = True) -> None:
        self._layout = _Layout(levels, pyramid_sigma, features, photometric, static_k)
        self.cuda_graphs = cuda_graphs
        self._graphs: dict[tuple[int, int], _Graph | None] = {}
        self.graph_failures = 0

    def run(self, gray: torch.Tensor) -> DescribeOutput:
        """Describe a (1, 1, H, W) float32 luminance tensor in [0, 1]."""
        layout = self._layout
        if not (self.cuda_graphs and gray.is_cuda):
            return layout.assemble(layout.tensors(gray))
        key = tuple(gray.shape[-2:])
        if key not in self._graphs:
            try:
                self._graphs[key] = _Graph(layout, gray)
            except RuntimeError as exc:  # an operation the capture refuses: run eagerly for this size
                self.graph_failures += 1
                self._graphs[key] = None
                _LOG.warning('describe could not be recorded as a CUDA graph for %dx%d frames (%s); it runs '
                             'operation by operation instead (slower, same results).', key[1], key[0], exc)
        graph = self._graphs[key]
        if graph is None:
            return layout.assemble(layout.tensors(gray))
        return layout.assemble(graph(gray), graph.skeleton)
