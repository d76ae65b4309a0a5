"""sensor_msgs/NavSatFix <-> :class:`~srmosaic_ros.core.types.GeoFix`."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from srmosaic_ros.core.types import GeoFix
from srmosaic_ros.errors import MessageError

from ._flavor import check_flavor, float_field, new_message
from .stamps import header_to_ns_frame, make_header

__all__ = ['navsat_to_fix', 'fix_to_navsat']

_LIMITS = {'latitude': 90.0, 'longitude': 180.0}


def navsat_to_fix(msg: Any) -> GeoFix:
    """GeoFix from a sensor_msgs/NavSatFix of either flavour.

    A fix whose ``status`` says no fix is passed on (``status`` = -1) as long as its numbers are
    valid; the consumer decides whether to use it.

    Raises:
        MessageError: NaN/infinite or out-of-range latitude, longitude or altitude, or a
            non-finite position_covariance; the message names the field.

    """
    stamp_ns, frame_id = header_to_ns_frame(msg)
    values: dict[str, float] = {}
    for name in ('latitude', 'longitude', 'altitude'):
        value = float(getattr(msg, name))
        if math.isnan(value) or math.isinf(value):
            what = 'NaN' if math.isnan(value) else 'infinite'
            msg_ = (
                f'NavSatFix.{name} is {what} (stamp {stamp_ns} ns); the receiver had no fix. '
                'Drop such messages upstream or wait for a valid fix.'
            )
            raise MessageError(msg_)
        limit = _LIMITS.get(name)
        if limit is not None and abs(value) > limit:
            msg_ = (
                f'NavSatFix.{name} {value} is outside [-{limit}, {limit}] degrees; '
                'the message is corrupt.'
            )
            raise MessageError(msg_)
        values[name] = value
    covariance = np.asarray(msg.position_covariance, dtype=np.float64).reshape(-1)
    if covariance.size != 9 or not np.all(np.isfinite(covariance)):
        msg_ = (
            f'NavSatFix.position_covariance must hold 9 finite values, got {covariance.tolist()}; '
            'set position_covariance_type to 0 (unknown) and zeros if the receiver gives none.'
        )
        raise MessageError(msg_)
    return GeoFix(
        stamp_ns=stamp_ns,
        latitude_deg=values['latitude'],
        longitude_deg=values['longitude'],
        altitude_m=values['altitude'],
        status=int(msg.status.status),
        position_covariance_m2=covariance.reshape(3, 3).copy(),
        covariance_type=int(msg.position_covariance_type),
        frame_id=frame_id,
    )


def fix_to_navsat(fix: GeoFix, *, flavor: str = 'rclpy') -> Any:
    """sensor_msgs/NavSatFix of ``flavor`` from a GeoFix (service left unknown)."""
    flavor = check_flavor(flavor)
    status = new_message(flavor, 'sensor_msgs/msg/NavSatStatus', status=int(fix.status), service=0)
    return new_message(
        flavor,
        'sensor_msgs/msg/NavSatFix',
        header=make_header(fix.stamp_ns, fix.frame_id, flavor),
        status=status,
        latitude=float(fix.latitude_deg),
        longitude=float(fix.longitude_deg),
        altitude=float(fix.altitude_m),
        position_covariance=float_field(np.asarray(fix.position_covariance_m2).reshape(9), flavor),
        position_covariance_type=int(fix.covariance_type),
    )
