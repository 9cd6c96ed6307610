"""Qt views of core models (DESIGN section 2). Widgets take the model in their constructor,
subscribe to its changes and display arrays computed in core; they never import ``app``."""
import pyqtgraph as pg

pg.setConfigOptions(imageAxisOrder="row-major", antialias=False, background="w", foreground="k")
