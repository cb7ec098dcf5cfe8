from __future__ import annotations

import json
import logging

from lessmap.cli.logfmt import JsonFormatter


def test_json_lines_carry_message_and_extra_fields() -> None:
    record = logging.LogRecord("lessmap.x", logging.INFO, __file__, 1, "opened %s", ("r1",), None)
    record.event = "session_opened"
    line = JsonFormatter().format(record)
    entry = json.loads(line)
    assert entry["msg"] == "opened r1"
    assert entry["level"] == "INFO"
    assert entry["event"] == "session_opened"
    assert entry["ts"].endswith("Z")
    assert "\n" not in line


def test_json_lines_include_tracebacks() -> None:
    try:
        1 / 0  # noqa: B018
    except ZeroDivisionError:
        import sys

        record = logging.LogRecord("x", logging.ERROR, __file__, 1, "boom", (), sys.exc_info())
    entry = json.loads(JsonFormatter().format(record))
    assert "ZeroDivisionError" in entry["exc"]


def test_configure_installs_one_handler_of_the_chosen_format() -> None:
    from lessmap.cli.logfmt import configure

    root = logging.getLogger()
    saved = root.handlers[:], root.level
    try:
        configure(logging.DEBUG, "json")
        configure(logging.INFO, "json")  # again: still one handler
        [handler] = root.handlers
        assert isinstance(handler.formatter, JsonFormatter)
        assert root.level == logging.INFO
        configure(logging.WARNING, "text")
        [handler] = root.handlers
        assert not isinstance(handler.formatter, JsonFormatter)
    finally:
        root.handlers[:], level = saved
        root.setLevel(level)


def test_tagged_lines_name_the_worker_in_text_and_json() -> None:
    import io

    from lessmap.cli.logfmt import configure, tag_lines

    root = logging.getLogger()
    saved = (root.handlers[:], root.level)
    try:
        for fmt in ("text", "json"):
            configure(logging.INFO, fmt)
            stream = io.StringIO()
            handler = root.handlers[0]
            assert isinstance(handler, logging.StreamHandler)
            handler.setStream(stream)
            tag_lines("w1")
            logging.getLogger("lessmap.x").info("took %d", 3)
            line = stream.getvalue().strip()
            if fmt == "json":
                assert json.loads(line)["worker"] == "w1"
            else:
                assert line.endswith("INFO w1 lessmap.x: took 3")
    finally:
        root.handlers[:], level = saved
        root.setLevel(level)
