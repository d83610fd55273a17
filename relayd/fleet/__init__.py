"""The fleet view: one page at the command center for the whole chain of relays.

`relayd fleet` polls every relay's /status on its own task (config: relayd.fleet.config,
polling: poller, the chain document: chain, the web app: server) and serves a page with
the chain from the leader through the relays to the command center, and a hold-all button.
"""
