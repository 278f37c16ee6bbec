"""A page's refreshes paced by the browser that draws them.

The server pulls the engine's new rows for each page every few hundred milliseconds and sends
the changes; a browser that draws slower than that (a busy laptop, a phone, software WebGL)
would queue them: each click then waits behind seconds of drawing. :class:`Pacer` is a
component of no size in each page: the server numbers each refresh it sends (``sent``), and the
page, once it has drawn that refresh (the next animation frame after the change arrived), says
so (``drawn``). The dashboard sends a refresh only when the last one is drawn, or after
:data:`DRAW_WAIT_SECONDS` (a page whose frames stopped: a hidden tab, a lost message), so at most
one refresh ever waits in a browser.
"""

from __future__ import annotations

import param
from panel.reactive import ReactiveHTML

DRAW_WAIT_SECONDS = 5.0
"""The longest a page's refreshes wait for it to say it drew the last one."""

DRAWN = "requestAnimationFrame(() => { data.drawn = data.sent })"


class Pacer(ReactiveHTML):
    """``sent``: the number of the server's last refresh; ``drawn``: the last one the page drew."""

    sent = param.Integer(default=0)
    drawn = param.Integer(default=0)

    _template = '<div id="pace"></div>'
    _scripts = {"render": DRAWN, "sent": DRAWN}

    def waiting(self) -> bool:
        """Whether the page has yet to draw the last refresh sent."""
        return self.drawn < self.sent
