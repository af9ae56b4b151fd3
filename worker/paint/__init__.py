"""The car-paint designer (cacad-cosine-lobes §3-4), independent of any renderer: the industry
measurement geometries (geometry.py), the paint database (database.py, data/), the
Levenberg-Marquardt basis exponents (exponents.py), the real-time lobe fit (fit.py), the
session's ``paint`` message (session.py) and ``glint paint`` (cli.py). The renderer that draws
its lobes materials is worker/renderers/paint/."""
