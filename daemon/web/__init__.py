"""The front door: an HTTP API inside the daemon that slicers send jobs to.

OctoPrint-compatible (``/api/...``) and Moonraker-compatible (``/server/...``,
``/printer/...``) endpoints, behind an API key; an upload becomes a spool job.
"""
