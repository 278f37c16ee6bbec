"""The served lab: ``granlab serve``'s panel server, the dashboard of each tab, the viser scene, the
engine's thread and what it reads and writes beside the simulation (see docs/lab.md)."""
