"""Processes that need no solver import none: the georef node, the map server, the tile recorder,
`srmosaic serve` and `srmosaic --help` start without torch (and the map server and the recorder
without filterpy and scipy), and the lazy packages still give every public name where it was."""
from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys

import pytest

#: (what starts, the modules its process imports before it works, libraries it must not load)
LIGHT = [
    ('georef_node', ['srmosaic_ros.nodes.georef_node', 'srmosaic_ros.nodes.runner'], ['torch']),
    ('map_server', ['srmosaic_ros.nodes.map_server', 'srmosaic_ros.nodes.runner', 'srmosaic_ros.web.server'],
     ['torch', 'filterpy', 'scipy']),
    ('tile_recorder', ['srmosaic_ros.nodes.tile_recorder', 'srmosaic_ros.nodes.runner', 'srmosaic_ros.io.output_dir'],
     ['torch', 'filterpy', 'scipy']),
    ('serve', ['srmosaic_ros.web.run_source', 'srmosaic_ros.web.server'], ['torch', 'filterpy', 'scipy']),
    ('configuration', ['srmosaic_ros.config', 'srmosaic_ros.nodes.parameters'], ['torch', 'filterpy', 'scipy']),
]

_PROBE = ('import importlib, json, sys\n'
          'for m in sys.argv[2:]: importlib.import_module(m)\n'
          'print(json.dumps([h for h in json.loads(sys.argv[1]) if h in sys.modules]))\n')


def loaded(code: str, *args: str) -> list[str]:
    """Run ``code`` in a fresh interpreter; its last stdout line (JSON)."""
    out = subprocess.run([sys.executable, '-c', code, *args], check=True, capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, OMP_NUM_THREADS='1')).stdout
    return json.loads(out.splitlines()[-1])


@pytest.mark.parametrize(('name', 'modules', 'banned'), LIGHT, ids=[row[0] for row in LIGHT])
def test_process_imports_no_solver(name: str, modules: list[str], banned: list[str]) -> None:
    assert loaded(_PROBE, json.dumps(banned), *modules) == [], f'{name} imports what it does not need'


def test_the_probe_sees_a_heavy_import() -> None:
    # the check above can fail: the mosaic node does need torch (registration) and filterpy (the UKF)
    assert loaded(_PROBE, json.dumps(['torch', 'filterpy']), 'srmosaic_ros.nodes.mosaic_node') == ['torch', 'filterpy']


def test_cli_help_imports_no_solver() -> None:
    code = ('import json, sys\n'
            'from srmosaic_ros import cli\n'
            'try:\n    cli.main(["--help"])\nexcept SystemExit:\n    pass\n'
            'print(json.dumps([h for h in ("torch", "filterpy", "scipy", "rclpy") if h in sys.modules]))\n')
    assert loaded(code) == []


@pytest.mark.parametrize('package', ['srmosaic_ros.core.registration', 'srmosaic_ros.core.sr', 'srmosaic_ros.core.georef'])
def test_lazy_packages_give_every_public_name(package: str) -> None:
    module = importlib.import_module(package)
    for name in module.__all__:
        assert getattr(module, name) is not None, name
        assert name in dir(module)
    with pytest.raises(AttributeError, match='no attribute'):
        module.not_a_name  # noqa: B018


def test_moved_names_are_the_same_objects() -> None:
    from srmosaic_ros.core.georef import ukf, ukf_models
    from srmosaic_ros.core.sr import dense_flow, local_align, modes, operators, ringing, robust_pixels, solvers
    from srmosaic_ros.live import placement, raster, sr

    assert ukf.UkfParams is ukf_models.UkfParams
    assert sr.ImagePlacement is raster.ImagePlacement is placement.ImagePlacement
    assert sr.SRTilePlacement is placement.SRTilePlacement
    assert (dense_flow.FLOW_MODES, local_align.ALIGN_MODES, operators.WARP_MODES, ringing.CLAMP_MODES,
            robust_pixels.ROBUST_NORMS, solvers.LAMBDA_MODES, solvers.SOLVERS) == (
        modes.FLOW_MODES, modes.ALIGN_MODES, modes.WARP_MODES, modes.CLAMP_MODES, modes.ROBUST_NORMS,
        modes.LAMBDA_MODES, modes.SOLVERS)
