"""lghcc.viewer (informative): ``lghcc-view``, a decoded stream as one self-contained HTML page
with a WebGL splat renderer (cli.py), the decoded-scene -> 3DGS seam (scenes.py) and the page
(page.py, web/). The renderer's JavaScript bundle (assets/) is built at set-up time:
``make viewer-bundle``."""
