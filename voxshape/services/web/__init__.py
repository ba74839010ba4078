"""`voxshape web`: the teachers' web page. gateway.py, frames.py, browser_clock.py,
page_json.py and robots.py are the pure core (bus messages <-> browser JSON), server.py the
aiohttp server bridged to the bus, node.py the command; static/ is the page itself."""


def page_url(address: str, port: int | str, https: bool) -> str:
    """Where a browser on this host opens the page served on `address`:`port`."""
    host = "localhost" if address in ("0.0.0.0", "::", "") else address
    host = f"[{host}]" if ":" in host else host
    return f"{'https' if https else 'http'}://{host}:{port}/"
