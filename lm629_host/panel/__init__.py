"""``lm629 panel``: the bench in a browser (docs/panel.md).

:mod:`.bench`: the thread that owns the board, samples it and runs the page's commands;
:mod:`.commands`: the page's forms as ``lm629`` command lines, and the step test's prediction;
:mod:`.server`: the standard library's HTTP server, its Host, Origin and token checks;
``static/``: the page, its script and the plotting library (uPlot, MIT licence beside it).
Nothing here is fetched at run time and nothing needs building.
"""
