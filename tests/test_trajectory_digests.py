"""Every trajectory of a fixed set is bit-identical to the stored digests.

The digests (`trajectory_digests.json`, written by `trajectory_digests.py`) were made on the
commit before a change of structure; a change that alters any number of any listed run fails
here. Digests are per host fingerprint: on a CPU model or engine build with none stored the
comparison is skipped, saying so (regenerate them there on a commit you trust).
"""

import json

import pytest
from trajectory_digests import DIGEST_FILE, RUNS, digest, host_fingerprint, run_id

_STORED = json.loads(DIGEST_FILE.read_text())
_HOST = host_fingerprint()


def test_every_run_has_a_digest_on_some_host():
    for host, digests in _STORED.items():
        assert sorted(digests) == sorted(run_id(r) for r in RUNS), host


@pytest.mark.parametrize("run", RUNS, ids=run_id)
def test_trajectory_is_bit_identical(run):
    if _HOST not in _STORED:
        pytest.skip(f"no digests stored for this host ({_HOST}); stored: {', '.join(_STORED)}")
    assert digest(run) == _STORED[_HOST][run_id(run)], (
        f"{run_id(run)}: the trajectory differs from the one stored for {_HOST}"
    )
