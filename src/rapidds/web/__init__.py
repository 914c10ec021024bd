"""The fetch game in a browser, with a real person as the teammate rapidds learns.

:mod:`.game` simulates one live cycle (the world's geometry, the plan's timeline semantics, the
avatar's physics); :mod:`.player` is the person as a :class:`~rapidds.worlds.base.Teammate` of
the adaptive loop (what the study harness reuses); :mod:`.session` runs the loop for one person
in a worker thread; :mod:`.protocol` validates what the browser sends; :mod:`.server` is the
FastAPI app with the fixed tick and the WebSocket; ``static/`` holds the page (plain HTML and
JavaScript, no build step). ``rapidds play`` (:mod:`rapidds.cli.play`) puts them together.

:mod:`.study` is the user-study app (``rapidds study serve``): a participant's rounds, surveys,
ranking and demographics as server-rendered pages over the study store.
"""
