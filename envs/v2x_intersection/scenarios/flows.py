"""Traffic flows and junction conflicts: actor flows, highway cut-ins and exits, merges, signalized and unsignalized junction priority, emergency vehicles.

Every class here registers itself with ``@register_scenario``.
"""

from __future__ import annotations
