"""Top-down rendering: the frame (:mod:`.topdown`), the town's static layer (:mod:`.map_layer`),
colours (:mod:`.palette`) and GIF / MP4 writing (:mod:`.video`).

``from v2xbench.envs.v2x_intersection.render import render_topdown, save_video`` works as
before the renderer became a folder.
"""

from .topdown import *  # noqa: F403
from .topdown import __all__  # noqa: F401
