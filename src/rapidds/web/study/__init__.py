"""The user study in the browser (``rapidds study serve``): :mod:`.runner` the protocol over the
study store (next step, the round's plan, one transaction per submit), :mod:`.app` the FastAPI
app, :mod:`.pages` the HTML, :mod:`.tracker` what a person did (tracker file, typed durations).
"""
