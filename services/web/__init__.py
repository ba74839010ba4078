"""`voxshape web`: the teachers' web page. gateway.py is the pure core (bus messages <->
browser JSON), node.py the aiohttp server bridged to the bus; static/ is the page itself."""
