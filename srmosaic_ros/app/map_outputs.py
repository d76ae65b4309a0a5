"""`process --tiles` and `--kmz`: the web map's XYZ tiles and the KMZ written into a finished run,
timed into its report (web/offline.py does the work)."""
from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from ..io.mosaic_files import write_json
from ..io.outputs import output_threads

__all__ = ['map_outputs']

_LOG = logging.getLogger(__name__)


def map_outputs(stage: Path, report: dict[str, Any], t0: float, *, tiles: str | None, kmz: bool) -> dict[str, Any]:
    """--tiles and --kmz into the finished run in ``stage`` (web/offline.py), timed into
    stage_times.outputs (``tiles_s``, ``kmz_s``, and their total_s); report.json written again."""
    if not (stage / 'mosaic.tif').is_file():
        why = ('--tiles and --kmz need a georeferenced mosaic (mosaic.tif), and this one is not: '
               f'{report.get("not_georeferenced_reason") or "no positions"}')
        _LOG.warning('%s', why)
        report['map_outputs'] = {'skipped': why}
        write_json(stage / 'report.json', report)
        return report
    from ..web.offline import write_kmz, write_tiles

    figures: dict[str, Any] = {}
    outputs = report.setdefault('stage_times', {}).setdefault('outputs', {})
    for name, wanted, write in (('tiles', tiles, lambda: write_tiles(stage, tiles, threads=output_threads(),
                                                                     report=report, name=stage.parent.resolve().name)),
                                ('kmz', kmz, lambda: write_kmz(stage))):
        if not wanted:
            continue
        t = time.perf_counter()
        figures[name] = write()
        spent = time.perf_counter() - t
        outputs[f'{name}_s'] = round(spent, 3)
        outputs['total_s'] = round(outputs.get('total_s', 0.0) + spent, 3)
    report['map_outputs'] = figures
    report['wall_s'] = round(time.perf_counter() - t0, 3)
    write_json(stage / 'report.json', report)
    return report
