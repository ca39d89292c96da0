"""Dataset format v1: typed readers, the validator and writers (see docs/dataset-format.md)."""

from .building import Building
from .dataset import Dataset
from .floor import FREE, OCCUPIED, UNKNOWN, Floor, Region
from .issues import Issue
from .schema import FORMAT, STREAMS
from .session import Session, check_session_in_building, sum_dropped
from .validate import validate

__all__ = ["FORMAT", "STREAMS", "Building", "Dataset", "Floor", "FREE", "Issue", "OCCUPIED",
           "Region", "Session", "UNKNOWN", "check_session_in_building", "sum_dropped", "validate"]
