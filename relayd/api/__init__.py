"""relayd's HTTP surface: status API, control endpoints, live page, metrics, OpenAPI."""

from relayd.api.app import make_app, start_api

__all__ = ["make_app", "start_api"]
