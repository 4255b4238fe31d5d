"""The hostile files are inputs for tests/test_hostile.py, not tests: keep the gate plugin
from collecting the broken gate files among them."""

collect_ignore_glob = ["files/*"]
