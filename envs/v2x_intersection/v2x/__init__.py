"""V2X: roadside-unit deployment and selection (:mod:`.rsu`), the channel between the RSU and the
ego (:mod:`.channel`: latency, loss, bandwidth), and the wire format (:mod:`.wire`).

:mod:`.wire` (NumPy) is the reference codec; :mod:`.jit_wire` packs the built-in policy's message
into the same bytes in one kernel (``tests/v2x/test_jit_wire.py``) and is skipped without numba.
"""
