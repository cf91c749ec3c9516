"""Obstacles on or beside the ego's road: accidents, construction, parked obstacles, door openings, cut-ins from parking.

Every class here registers itself with ``@register_scenario``.
"""

from __future__ import annotations
