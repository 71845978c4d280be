"""Pictures and pages of arm runs: videos, figures and the job's results page.

- ``sim.media.gl``: the OpenGL back-end for headless rendering, chosen lazily;
- ``sim.media.camera``: where the video camera stands, and projection to pixels;
- ``sim.media.overlay``: the 2-D overlays drawn into frames (paths, markers, legend);
- ``sim.media.render``: offscreen rendering of runs into MP4s;
- ``sim.media.plots``: figures of runs from their time series;
- ``sim.media.job_page``: an arm job's ``index.html``.

Above ``sim.control`` (a video's frames are taken at the loop's times), below ``sim.run``
(pyproject.toml's import contracts).
"""
