"""Many scenes at once on Ray: ``clearsplat batch`` and the benchmark's engine.

- :mod:`.scene`: one scene, a plain function (:func:`filter_scene`) writing what
  ``clearsplat filter`` writes;
- :mod:`.engine`: the Ray layer (start or join a cluster, run tasks, gather them as they end);
- :mod:`.run`: :func:`run_batch`, scenes from folders, globs and lists, resume, summaries;
- :mod:`.windows`: one long capture in windows of consecutive views
  (:func:`filter_windows`), in bounded memory, locally or as Ray tasks.

``ray`` is needed only to run on a cluster (``pip install 'clearsplat[batch]'``).
"""

from .engine import TaskFailed, ray_cluster, run_tasks
from .run import SUMMARY_FIELDS, find_scenes, run_batch, write_summary
from .windows import filter_windows, plan_windows
from .scene import (FILTER_FILES, estimate_scene_memory, filter_scene, is_complete,
                    ply_vertex_count, write_filter_outputs)

__all__ = ["filter_scene", "write_filter_outputs", "is_complete", "estimate_scene_memory",
           "ply_vertex_count", "FILTER_FILES", "find_scenes", "run_batch", "write_summary",
           "SUMMARY_FIELDS", "ray_cluster", "run_tasks", "TaskFailed", "filter_windows",
           "plan_windows"]
