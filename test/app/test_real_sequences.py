"""The real survey sequences (stills seconds apart, 60 to 90% overlap) register end to end."""
from __future__ import annotations


import pytest

from srmosaic_ros.config import pipeline_config
from srmosaic_ros.core.types import GeoFix
from srmosaic_ros.io.image_folder import ImageFolderReader, is_image_folder
from srmosaic_ros.pipeline import Pipeline
from repo_paths import REPO

SEQUENCES = REPO / 'data' / 'sequences'


@pytest.mark.parametrize(('name', 'frames'), [('brighton_beach', 18), ('caliterra', 14)])
def test_sequence_registers_into_one_segment(name, frames):
    path = SEQUENCES / name
    assert is_image_folder(path)
    reader = ImageFolderReader(path)
    pipe = Pipeline(pipeline_config())
    fixes = 0
    for item in reader:
        pipe.feed(item)
        fixes += isinstance(item, GeoFix)
    res = pipe.finish()
    assert len(res.records) == frames and fixes == frames
    assert all(r.painted for r in res.records), [r.reason for r in res.records if not r.painted]
    assert len(res.segments) == 1
    regs = [r.registration for r in res.records[1:]]
    assert min(r.inliers for r in regs) >= 20  # well above min_inliers (15) on the hardest pair
    assert max(r.rms_px for r in regs) < 1.5
    assert [r.stamp_ns for r in res.records] == sorted(r.stamp_ns for r in res.records)
