"""``tcm-companion bench``: what the service costs.

- :mod:`.pipeline` — per-stage time per frame of the pipeline, one core (``bench``).
- :mod:`.mavlink` — the endpoint's encode cost and the link latency (``bench --mavlink``).
- :mod:`.daemon` — the daemon as its own process, measured from outside (``bench --daemon``).
"""
