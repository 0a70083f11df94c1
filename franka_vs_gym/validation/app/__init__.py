"""``franka-vs workbench``: the workbench's loop in the browser (a local Bokeh server app).

- :mod:`.session`: what the page shows, computed without Bokeh: a log opened once (cleaned, the baseline model's
  residual and every effect's regressor columns), the enabled effects refitted by one small least-squares solve on
  the fit part of ``fit``'s time split, the held-out error, the diagnosis, saving the calibrated model and the
  report, validating a saved model on another log;
- :mod:`.arm`: the arm drawn by MuJoCo in the pose at the cursor's time, its links coloured by their joint's residual;
- :mod:`.page`: the Bokeh document (figures, toggles, tables, buttons);
- :mod:`.server`: the Bokeh server, bound to 127.0.0.1, serving its own BokehJS (nothing is requested outside the
  machine).
"""
