"""MosaicDiagnostics: the mosaic node's diagnostic status, built from its counters and the pipeline.

Keys (DESIGN.md's diagnostics contract): frames_received, frames_processed, dropped_frames,
frames_skipped_by_rate, frames_in_mosaic, segments, last_ok, last_inliers, last_rms_px,
last_reason, processing_ms_median, processing_ms_p95, the rejection counters, the filter's skips,
and while the pose check refuses placement pose_placement and the frames' mount to try. WARN while
frames are being dropped or inputs rejected (not for ever after), or while the pose check refuses.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

__all__ = ['MosaicDiagnostics']


class MosaicDiagnostics:
    """The status of one round (module docstring). ``warn``: the node's WarnOnce; ``publisher``: its
    DiagnosticsPublisher. :meth:`build` reads the pipeline: call it under the worker's lock or after it."""

    def __init__(self, warn: Any, publisher: Any) -> None:
        self._warn = warn
        self._publisher = publisher
        self._dropped_reported = warn.snapshot().get('dropped_frames', 0)  # as the last diagnostics said it

    def publish(self, worker: Any, active: bool) -> None:
        self._publisher.publish(self.build(worker, active))

    def build(self, worker: Any, active: bool) -> DiagnosticArray:
        """The DiagnosticArray of the worker's state (``worker``: a live.mosaic_worker.MosaicWorker)."""
        stats = self._warn.snapshot()
        pipeline = worker.pipeline
        rec = worker.last_record
        reg = rec.registration if rec is not None else None
        lat = np.array(worker.latency_ms) if worker.latency_ms else np.array([np.nan])
        values = {
            'frames_received': stats.get('frames_received', 0),
            'frames_processed': stats.get('frames_processed', 0),
            'dropped_frames': stats.get('dropped_frames', 0),
            'frames_skipped_by_rate': stats.get('frames_skipped_by_rate', 0),
            'frames_in_mosaic': sum(len(s.frames) for s in pipeline.segments),
            'segments': len(pipeline.segments),
            'last_ok': int(rec.painted) if rec else 0,
            'last_inliers': reg.inliers if reg else 0,
            'last_rms_px': f'{reg.rms_px:.3f}' if reg else 'nan',
            'last_reason': rec.reason if rec else '',
            'processing_ms_median': f'{np.median(lat):.1f}',
            'processing_ms_p95': f'{np.percentile(lat, 95):.1f}',
        }
        values.update({k: v for k, v in stats.items() if k.startswith(('rejected', 'preview_', 'camera_info_scaled'))})
        georef = pipeline.georef
        if georef is not None:  # as the standalone georef node says them (a copy: the worker fuses meanwhile)
            values.update({f'filter skipped: {k}': v for k, v in dict(georef.skipped).items()})
        level = DiagnosticStatus.OK
        message = 'registering'
        if rec is not None and not rec.painted:
            level, message = DiagnosticStatus.WARN, f'last frame not registered: {rec.reason}'
        dropped = stats.get('dropped_frames', 0)
        if dropped > self._dropped_reported:  # WARN while frames are being dropped, not for ever after
            level = DiagnosticStatus.WARN
            message += (f'; falling behind: {dropped - self._dropped_reported} frames dropped since the last report '
                        f'({dropped} in all; processing median {values["processing_ms_median"]} ms a frame)')
        elif dropped:
            message += f'; {dropped} frames dropped (falling behind) earlier'
        self._dropped_reported = dropped
        check = pipeline.pose_check
        if check is not None and not check.used:  # off the map for the rest of the run: WARN until restarted
            level = max(level, DiagnosticStatus.WARN)
            message += f'; {check.operator_note()}'
            values['pose_placement'] = 'refused'
            if check.mount_to_try is not None:
                values['frames_mount_azimuth_deg'], values['frames_mount_elevation_deg'] = check.mount_to_try
        if not active:
            message = 'inactive (lifecycle): inputs ignored, the mosaic kept'
            values['frames_while_inactive'] = stats.get('frames_while_inactive', 0)
        rejecting, message = self._warn.status(message)
        level = max(level, rejecting)  # WARN while messages are being rejected, not for ever after
        return self._publisher.array(message, values, level)
