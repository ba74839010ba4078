"""`voxshape web`: the teachers' web page. gateway.py is the pure core (bus messages <->
browser JSON), node.py the aiohttp server bridged to the bus; static/ is the page itself."""


def page_url(address: str, port: int | str, https: bool) -> str:
    """Where a browser on this host opens the page served on `address`:`port`."""
    host = "localhost" if address in ("0.0.0.0", "::", "") else address
    host = f"[{host}]" if ":" in host else host
    return f"{'https' if https else 'http'}://{host}:{port}/"
