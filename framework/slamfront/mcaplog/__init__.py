"""Run logs in MCAP: writing (:mod:`.writer`), reading (:mod:`.reader`) and the
Foxglove message builders (:mod:`.foxglove`)."""

from slamfront.mcaplog.reader import LogSummary, TopicSummary, read_messages, summarize
from slamfront.mcaplog.writer import RunLogWriter

__all__ = ["LogSummary", "RunLogWriter", "TopicSummary", "read_messages", "summarize"]
