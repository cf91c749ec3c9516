"""Evaluation: what happened during a tick and how an episode scores.

Collisions (:mod:`.physics`), infraction and route-progress events (:mod:`.infractions`, step 6
of a tick), rewards / termination / info shared by the adapters (:mod:`.episode`), closed-loop
metrics (:mod:`.metrics`) and open-loop / perception metrics (:mod:`.metrics_perception`).

NumPy / numba pairs: :mod:`.infractions` / :mod:`.jit_events` and :mod:`.physics`'s NumPy
separating-axis test / its ``ego_contacts_kernel``; the NumPy path is the reference the kernels
are tested against and the fallback without numba. :mod:`.jit_route` (the ego's continuous
progress) runs as plain Python without numba.
"""
