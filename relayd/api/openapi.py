"""The OpenAPI 3.0 description of relayd's HTTP API, served at /openapi.json.

The /status schema is generated from its typed model (`relayd.api.status`), translated
to OpenAPI 3.0's `nullable: true`. The request schemas are hand-written and must agree
with the pydantic models in `relayd.api.models`;
tests/api/test_app.py checks both against the same inputs, and schemathesis checks every
response against this document.
"""

from __future__ import annotations

from typing import Any

from relayd import __version__
from relayd.api.status import OwnPath, Status, openapi_schema
from relayd.core.vocab import DriveState, Mode


def _num(nullable: bool = True, **extra: Any) -> dict[str, Any]:
    return {"type": "number", "nullable": nullable, **extra}


def _obj(props: dict[str, Any], *, nullable: bool = False, required: bool = True) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "object", "properties": props}
    if required:
        schema["required"] = list(props)
    if nullable:
        schema["nullable"] = True
    return schema


def _error(description: str) -> dict[str, Any]:
    return {
        "description": description,
        "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Error"}}},
    }


def _json(description: str, ref: str) -> dict[str, Any]:
    return {
        "description": description,
        "content": {"application/json": {"schema": {"$ref": f"#/components/schemas/{ref}"}}},
    }


#: Generated from the typed model of the document (relayd.api.status.Status).
STATUS_SCHEMA: dict[str, Any] = openapi_schema(Status)
PATH_SCHEMA: dict[str, Any] = openapi_schema(OwnPath)


def _column(items: dict[str, Any]) -> dict[str, Any]:
    return {"type": "array", "items": items}


HISTORY_SCHEMA: dict[str, Any] = _obj(
    {
        "period_s": _num(False, description="seconds between samples"),
        "window_s": _num(False, description="how far back the daemon keeps samples"),
        "next_seq": {
            "type": "integer",
            "minimum": 0,
            "description": "the sequence number the next sample will get",
        },
        "thresholds": {"type": "object", "additionalProperties": {"type": "number"}},
        "samples": _obj(
            {
                "seq": _column({"type": "integer", "minimum": 0}),
                "age_s": _column({"type": "number", "minimum": 0}),
                "rssi_leader_dbm": _column(_num()),
                "rssi_behind_dbm": _column(_num()),
                "bearing_deg": _column(_num()),
                "state": _column({"type": "string", "enum": [s.value for s in DriveState]}),
                "x_mm": _column(_num()),
                "y_mm": _column(_num()),
                "theta_deg": _column(_num()),
            }
        ),
    }
)


def build_openapi(max_drive_mm_s: float) -> dict[str, Any]:
    """The document for an app whose drive limit is `max_drive_mm_s`."""
    wheel = {"type": "number", "minimum": -max_drive_mm_s, "maximum": max_drive_mm_s}
    secured: list[dict[str, list[str]]] = [{"bearer": []}]
    control_errors = {
        "400": _error(
            "bad JSON, or a missing, unknown, wrong-typed or out-of-range field (named in `field`)"
        ),
        "401": _error("no or wrong bearer token"),
        "403": _error("no API token is configured: control endpoints are disabled"),
        "409": _error("the current mode does not allow this request"),
        "429": _error("too many failed authentications from this client: wait Retry-After s"),
        "413": {"description": "request body too large"},
    }
    return {
        "openapi": "3.0.3",
        "info": {
            "title": "relayd",
            "version": __version__,
            "description": "Status and control of one Wi-Fi relay robot.",
        },
        "paths": {
            "/status": {
                "get": {
                    "summary": "Everything the robot knows right now",
                    "operationId": "getStatus",
                    "responses": {"200": _json("the status document", "Status")},
                }
            },
            "/path": {
                "get": {
                    "summary": "This relay's odometry pose and the path it drove, for a relay "
                    "that follows it (read-only)",
                    "operationId": "getPath",
                    "responses": {"200": _json("the pose and the path", "Path")},
                }
            },
            "/healthz": {
                "get": {
                    "summary": "Liveness of the control loop",
                    "operationId": "getHealthz",
                    "responses": {
                        "200": _json("the control loop ticked recently", "Health"),
                        "503": _json(
                            "the control loop is not ticking; `reason` says why", "Health"
                        ),
                    },
                }
            },
            "/history": {
                "get": {
                    "summary": "The last minutes of RSSI^l, RSSI^b, bearing, state and pose, as "
                    "columns, oldest first (a bounded ring buffer in the daemon)",
                    "operationId": "getHistory",
                    "parameters": [
                        {
                            "name": "after",
                            "in": "query",
                            "required": False,
                            "description": "only samples with a larger seq (-1 or absent: all); a value "
                            "beyond the newest returns all, the daemon having restarted",
                            "schema": {"type": "integer", "minimum": -1},
                        }
                    ],
                    "responses": {
                        "200": _json("samples, each column in the same order", "History"),
                        "400": _error("`after` is not an integer >= -1"),
                    },
                }
            },
            "/metrics": {
                "get": {
                    "summary": "Prometheus metrics",
                    "operationId": "getMetrics",
                    "responses": {
                        "200": {
                            "description": "Prometheus text exposition",
                            "content": {"text/plain": {"schema": {"type": "string"}}},
                        }
                    },
                }
            },
            "/events": {
                "get": {
                    "summary": "Server-Sent Events: `status` events carrying the status document, "
                    "`heartbeat` events while nothing changes",
                    "operationId": "getEvents",
                    "responses": {
                        "200": {
                            "description": "an endless event stream",
                            "content": {"text/event-stream": {"schema": {"type": "string"}}},
                        },
                        "503": _error(
                            "too many event streams (in all or from this client): poll /status"
                        ),
                    },
                }
            },
            "/openapi.json": {
                "get": {
                    "summary": "This document",
                    "operationId": "getOpenapi",
                    "responses": {
                        "200": {
                            "description": "OpenAPI 3.0 document",
                            "content": {"application/json": {"schema": {"type": "object"}}},
                        }
                    },
                }
            },
            "/": {
                "get": {
                    "summary": "The live page",
                    "operationId": "getLivePage",
                    "responses": {
                        "200": {
                            "description": "HTML page",
                            "content": {"text/html": {"schema": {"type": "string"}}},
                        }
                    },
                }
            },
            "/api/mode": {
                "post": {
                    "summary": "Change the operating mode (hold needs no token: a stop is "
                    "always allowed; follow and manual need the bearer token)",
                    "operationId": "setMode",
                    "security": [*secured, {}],
                    "requestBody": {
                        "required": True,
                        "content": {
                            "application/json": {
                                "schema": {"$ref": "#/components/schemas/ModeRequest"}
                            }
                        },
                    },
                    "responses": {"200": _json("mode changed", "ModeResponse"), **control_errors},
                }
            },
            "/api/drive": {
                "post": {
                    "summary": "Drive the wheels (manual mode only; expires after the dead-man time)",
                    "operationId": "drive",
                    "security": secured,
                    "requestBody": {
                        "required": True,
                        "content": {
                            "application/json": {
                                "schema": {"$ref": "#/components/schemas/DriveRequest"}
                            }
                        },
                    },
                    "responses": {
                        "200": _json("command accepted", "DriveResponse"),
                        **control_errors,
                    },
                }
            },
        },
        "components": {
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"}},
            "schemas": {
                "Status": STATUS_SCHEMA,
                "Path": PATH_SCHEMA,
                "History": HISTORY_SCHEMA,
                "Health": {
                    "type": "object",
                    "required": ["ok"],
                    "properties": {
                        "ok": {"type": "boolean"},
                        "reason": {"type": "string"},
                        "loop_age_s": _num(),
                        "max_age_s": _num(False),
                        "mode": {"type": "string", "enum": [m.value for m in Mode]},
                        "state": {"type": "string", "enum": [s.value for s in DriveState]},
                    },
                },
                "Error": {
                    "type": "object",
                    "required": ["error"],
                    "properties": {
                        "error": {"type": "string"},
                        "field": {"type": "string", "nullable": True},
                        "mode": {"type": "string", "enum": [m.value for m in Mode]},
                    },
                },
                "ModeRequest": {
                    "type": "object",
                    "required": ["mode"],
                    "additionalProperties": False,
                    "properties": {"mode": {"type": "string", "enum": [m.value for m in Mode]}},
                },
                "ModeResponse": {
                    "type": "object",
                    "required": ["ok", "mode"],
                    "properties": {
                        "ok": {"type": "boolean"},
                        "mode": {"type": "string", "enum": [m.value for m in Mode]},
                    },
                },
                "DriveRequest": {
                    "type": "object",
                    "required": ["left_mm_s", "right_mm_s"],
                    "additionalProperties": False,
                    "properties": {"left_mm_s": wheel, "right_mm_s": wheel},
                },
                "DriveResponse": {
                    "type": "object",
                    "required": ["ok", "left_mm_s", "right_mm_s"],
                    "properties": {
                        "ok": {"type": "boolean"},
                        "left_mm_s": {"type": "number"},
                        "right_mm_s": {"type": "number"},
                    },
                },
            },
        },
    }
