"""Pictures and movies without a server: ``granlab render``, the lab's recordings, and the colours
every picture of GranLab shares (the live scene's included)."""
