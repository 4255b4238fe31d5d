"""The trajectory table every engine returns, with the run's metadata: the suite's contract.

One row per sample per body, columns `COLUMNS` (plus optional ones such as `shape_error`):
COM position and velocity (world, m and m/s), orientation quaternion (w, x, y, z) mapping the
body's placement at t = 0 to its current one, world-frame angular velocity (rad/s). An engine
whose bodies deform (the reference's `seed`) also records where every particle is
(`Trajectory.particles`): the pose places a rigid body's particles, not a deforming one's.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import tempfile
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from functools import cache, cached_property
from importlib import metadata
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from cases.errors import InputError

POSITION = ["x", "y", "z"]
QUATERNION = ["qw", "qx", "qy", "qz"]
VELOCITY = ["vx", "vy", "vz"]
ANGULAR_VELOCITY = ["wx", "wy", "wz"]
STATE = POSITION + QUATERNION + VELOCITY + ANGULAR_VELOCITY
COLUMNS = ["t", "body", *STATE]
META_KEY = b"rigidbench"
# Where a results-cache entry keeps its stamp (`comparators.cache`): its run key and the
# `content_checksum` of what it holds.
STAMP_KEY = b"rigidbench.entry"
# The Parquet column holding `Trajectory.particles`: per table row, that body's particles at
# that sample as a list x0, y0, z0, x1, ... (a list column, so bodies of any size share it).
PARTICLES_COLUMN = "particles"


def package_versions(*names: str) -> dict[str, str]:
    """Versions of Python, rigidbench and the named distributions (missing ones are skipped)."""
    return dict(_versions(names))


@cache
def _versions(names: tuple[str, ...]) -> tuple[tuple[str, str], ...]:
    # looked up once per process: a sweep asks for every run
    out = {"python": platform.python_version()}
    for name in ("rigidbench", "numpy", *names):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return tuple(out.items())


@dataclass(frozen=True)
class RunMeta:
    """What produced a trajectory. Times in seconds; `wall_s` is stepping alone.

    `settings` is the parity manifest: every engine setting that affects the result.
    `bodies` maps body names to the model read back from the engine before stepping
    (`comparators.parity.body_readback`): mass, inertia, x, v, w. `solver` is what the engine
    reports about its own contact solver over the run, where it reports anything: `solves`,
    `sweeps_per_solve`, `at_limit` (solves stopped unconverged: at the iteration limit, or
    stalled), `subspace_per_solve` (the reference's direct solves within its sweeps),
    `extrapolations_per_solve` (the reference's jumps along its sweeps' steady rate) and
    `refound` (the reference's steps started again: a solve outran their candidates).
    `messages` is what the engine printed or warned during the run: each distinct line (capped
    in number and length) and how often it came, in order of first appearance
    (`comparators.engine_output`).
    """

    case: str
    engine: str
    integrator: str
    dt: float
    steps: int
    duration: float
    setup_s: float
    wall_s: float
    versions: dict[str, str] = field(default_factory=dict)
    settings: dict[str, object] = field(default_factory=dict)
    bodies: dict[str, dict] = field(default_factory=dict)
    wall_runs: list[float] = field(default_factory=list)  # every timing when repeated
    solver: dict[str, float] = field(default_factory=dict)
    messages: dict[str, int] = field(default_factory=dict)

    @property
    def steps_per_s(self) -> float:
        return self.steps / self.wall_s if self.wall_s > 0 else float("inf")


@dataclass(frozen=True)
class Trajectory:
    """A run's table and metadata.

    Attributes:
      table: one row per sample per body (`COLUMNS`, plus optional columns).
      meta: what produced it.
      particles: by body name, (S, n, 3) world positions (m) of the body's n particles at each
        of its S samples (in table order), or None: recorded only where the pose cannot place
        them (a deforming body). Written to and read from Parquet (so the results cache keeps
        them); a CSV file holds the table alone.
    """

    table: pd.DataFrame
    meta: RunMeta
    particles: dict[str, np.ndarray] | None = field(default=None, compare=False)

    @classmethod
    def from_samples(
        cls, times, bodies, samples, meta: RunMeta, extra=None, particles=None
    ) -> Trajectory:
        """Build from times (S,), body names (B,), samples (S, B, 13) in `STATE` order.

        `extra` maps optional column names to (S, B) arrays; `particles` maps body names to
        (S, n, 3) particle positions (`Trajectory.particles`), or is None.
        """
        samples = np.asarray(samples, dtype=float)
        n_s, n_b = samples.shape[:2]
        data = {
            "t": np.repeat(np.asarray(times, dtype=float), n_b),
            "body": np.tile(np.asarray(bodies, dtype=object), n_s),
        }
        flat = samples.reshape(n_s * n_b, len(STATE))
        data.update({c: flat[:, k] for k, c in enumerate(STATE)})
        for name, values in (extra or {}).items():
            data[name] = np.asarray(values, dtype=float).reshape(n_s * n_b)
        if particles is not None:
            particles = {name: np.asarray(p, dtype=float) for name, p in particles.items()}
            for name, p in particles.items():
                if p.ndim != 3 or p.shape[0] != n_s or p.shape[2] != 3:
                    raise ValueError(
                        f"particles of body {name!r} have shape {p.shape}: expected "
                        f"({n_s}, n, 3), the positions of its n particles at each sample"
                    )
            if sorted(particles) != sorted(map(str, bodies)):
                raise ValueError(
                    f"particles for bodies {sorted(particles)}: expected every body's, "
                    f"{sorted(map(str, bodies))}"
                )
        return cls(pd.DataFrame(data), meta, particles)

    @property
    def bodies(self) -> list[str]:
        return list(dict.fromkeys(self.table["body"]))

    @cached_property
    def state_by_body(self) -> dict[str, np.ndarray]:
        """Per body, its rows of t and the `STATE` columns as one (S, 14) float array, in table
        order. Converted from the table once per trajectory: every metric reads these, and
        converting the table per body and metric cost N^2 for N bodies."""
        values = self.table[["t", *STATE]].to_numpy(dtype=float)
        names, owner = np.unique(self.table["body"].to_numpy(dtype=str), return_inverse=True)
        order = np.argsort(owner, kind="stable")
        ends = np.cumsum(np.bincount(owner, minlength=len(names)))
        parts = np.split(values[order], ends[:-1])
        return dict(zip(names.tolist(), parts, strict=True))

    def body(self, name: str) -> pd.DataFrame:
        """The rows of one body, in time order."""
        return self.table[self.table["body"] == name].reset_index(drop=True)

    def write(self, path: str | os.PathLike, stamp: dict[str, str] | None = None) -> Path:
        """Write .csv (metadata beside it in FILE.meta.json) or .parquet (metadata inside).

        Files are written to a temporary name and renamed, so nothing is ever half-written.
        `stamp` (Parquet only) is stored beside the metadata, with "checksum" set to the
        `content_checksum` of what is written; `read_stamped` reads it back.
        """
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in (".csv", ".parquet"):
            raise InputError(f"output file {str(path)!r}: expected a .csv or .parquet name")
        if not path.parent.is_dir():
            raise InputError(f"output file {str(path)!r}: directory {str(path.parent)!r} missing")
        meta = json.dumps(asdict(self.meta), default=str).encode()
        if suffix == ".csv":
            _atomic_write(path.with_name(path.name + ".meta.json"), meta)
            _atomic_write(path, self.table.to_csv(index=False, float_format="%.17g").encode())
        else:
            table = pa.Table.from_pandas(self.table, preserve_index=False)
            if self.particles is not None:
                table = table.append_column(PARTICLES_COLUMN, self._particle_lists())
            extra = {META_KEY: meta}
            if stamp is not None:
                stamp = {**stamp, "checksum": content_checksum(meta, self.table, self.particles)}
                extra[STAMP_KEY] = json.dumps(stamp, sort_keys=True).encode()
            table = table.replace_schema_metadata({**table.schema.metadata, **extra})
            with atomic_path(path) as tmp:
                pq.write_table(table, tmp)
        return path

    def _particle_lists(self) -> pa.LargeListArray:
        """`particles` as the Parquet list column `PARTICLES_COLUMN`: per table row, that body's
        particles at that sample, x0, y0, z0, x1, ..."""
        owner = self.table["body"].to_numpy(dtype=str)
        sizes = np.zeros(len(owner), dtype=np.int64)
        for name, p in self.particles.items():
            sizes[owner == name] = p.shape[1] * 3
        offsets = np.concatenate([[0], np.cumsum(sizes)])
        values = np.empty(offsets[-1])
        for name, p in self.particles.items():
            starts = offsets[:-1][owner == name]
            values[starts[:, None] + np.arange(p.shape[1] * 3)] = p.reshape(len(p), -1)
        return pa.LargeListArray.from_arrays(pa.array(offsets), pa.array(values))

    @classmethod
    def read(cls, path: str | os.PathLike) -> Trajectory:
        path = Path(path)
        if path.suffix.lower() == ".csv":
            table = pd.read_csv(path)
            meta = json.loads(path.with_name(path.name + ".meta.json").read_text())
            return cls(table, RunMeta(**meta))
        return cls._read_parquet(path)[0]

    @classmethod
    def read_stamped(cls, path: str | os.PathLike) -> tuple[Trajectory, dict | None, str]:
        """A .parquet file's trajectory, the stamp `write` stored (None if none), and the
        `content_checksum` of what was read, to compare with the stamp's."""
        traj, metadata = cls._read_parquet(path)
        stamp = json.loads(metadata[STAMP_KEY]) if STAMP_KEY in metadata else None
        return traj, stamp, content_checksum(metadata[META_KEY], traj.table, traj.particles)

    @classmethod
    def _read_parquet(cls, path) -> tuple[Trajectory, dict[bytes, bytes]]:
        arrow = pq.read_table(path)
        metadata = arrow.schema.metadata
        meta = RunMeta(**json.loads(metadata[META_KEY]))
        if PARTICLES_COLUMN in arrow.column_names:
            lists = arrow.column(PARTICLES_COLUMN).combine_chunks()
            table = arrow.drop_columns([PARTICLES_COLUMN]).to_pandas()
            return cls(table, meta, _particles_from_lists(table, lists)), metadata
        return cls(arrow.to_pandas(), meta), metadata


def content_checksum(meta: bytes, table: pd.DataFrame, particles: dict | None) -> str:
    """SHA-256 of a trajectory's content as stored: the metadata's bytes, every column (name,
    type, values) and every body's particles. The same before writing and after reading back."""
    digest = hashlib.sha256(meta)
    for name, column in table.items():
        values = column.to_numpy()
        digest.update(f"\0column {name} {values.dtype.kind}".encode())
        if values.dtype.kind in "biuf":
            digest.update(values.dtype.str.encode())
            digest.update(np.ascontiguousarray(values).tobytes())
        else:  # text (body names): codes into the distinct values, then the values
            codes, uniques = pd.factorize(column)
            digest.update(codes.astype(np.int64).tobytes())
            digest.update(json.dumps([str(u) for u in uniques]).encode())
    for name in sorted(particles or {}):
        p = np.ascontiguousarray(particles[name], dtype=float)
        digest.update(f"\0particles {name} {p.shape}".encode())
        digest.update(p.tobytes())
    return digest.hexdigest()


def _particles_from_lists(table: pd.DataFrame, lists: pa.LargeListArray) -> dict[str, np.ndarray]:
    """`Trajectory.particles` from the list column `Trajectory._particle_lists` wrote."""
    owner = table["body"].to_numpy(dtype=str)
    offsets = lists.offsets.to_numpy()
    values = lists.values.to_numpy()
    particles = {}
    for name in dict.fromkeys(owner):
        rows = np.flatnonzero(owner == name)
        size = offsets[rows[0] + 1] - offsets[rows[0]]
        flat = values[offsets[rows][:, None] + np.arange(size)]
        particles[name] = flat.reshape(len(rows), size // 3, 3)
    return particles


_UMASK = os.umask(0)
os.umask(_UMASK)


@contextmanager
def atomic_path(path: Path):
    """Yield a temporary path beside `path`; rename it to `path` only if the block succeeds."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the file a normal file's mode
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def _atomic_write(path: Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(data)
