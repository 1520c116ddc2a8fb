"""Alarms and operator messages: the catalogue, the persistent history, and the book of active alarms."""

from cnc.alarms.book import AlarmBook
from cnc.alarms.catalogue import AlarmAction, AlarmLevel, Catalogue, CatalogueEntry, UnknownAlarm
from cnc.alarms.history import MAX_PAGE, AlarmHistory, HistoryError

__all__ = [
    "MAX_PAGE", "AlarmAction", "AlarmBook", "AlarmHistory", "AlarmLevel", "Catalogue", "CatalogueEntry",
    "HistoryError", "UnknownAlarm",
]
