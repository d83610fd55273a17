"""relayd's HTTP surface: status API, control endpoints, live page, metrics, OpenAPI."""

from relayd.api.app import make_app
from relayd.api.server import ApiServer, start_api

__all__ = ["ApiServer", "make_app", "start_api"]
