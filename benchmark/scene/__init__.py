"""The interactive tools on a scene folder (a benchmark run, a fitted capture, an edited scene).

* ``folders``: what ``render``, ``edit`` and ``view`` open: one ``SceneFolder`` (model,
  clusters, cameras) per folder, and the selection rules (cluster ids, clicks, the run's prompts);
* ``render``: ``trase-bench render``, frames, an MP4 and an animated preview;
* ``edit``: ``trase-bench edit``, one edit written as a new, reopenable folder;
* ``viewer``: ``trase-bench view``, a web viewer rendered on the server.

Nothing is imported here: each module pulls in torch and the renderer when it is used.
"""
