"""``photonmap view``: interactive relighting in the browser (Sun et al. 2008 §6:
drag the light, change the glass, paint fog, see the caustics follow).

A FastAPI server (:mod:`.app`) with one static page (``static/``) over a render thread
(:mod:`.worker`) that drives a pipeline through its adapter (:mod:`.adapters`); the state
document and its checks are in :mod:`.state`. Needs the ``viewer`` extra
(``pip install photonmap[viewer]``: FastAPI, uvicorn, websockets, Pillow).

>>> viewer = Viewer("glass_sphere_fog", "volume", {"grid": 64}, size=(320, 240))
>>> serve(viewer, port=8000)            # page_url(viewer): http://127.0.0.1:8000/?token=…
>>> with Background(viewer) as bg: ...   # on a thread: bg.page_url, bg.url + bg.headers
"""

from .app import Background, Viewer, create_app, page_url, serve

__all__ = ["Background", "Viewer", "create_app", "page_url", "serve"]
