"""Per-worker set-up owned by the skeleton (:mod:`holofit.batch.worker`): a resource is made
once per worker process and key and reused by every item; the least recently used is closed
when a newer one pushes it out; a forked process starts without its parent's."""

from __future__ import annotations

import pandas as pd
import pytest

from holofit.batch import BatchSettings, release_worker_resources, run_batch, worker_resource
from holofit.batch import worker as worker_module
from holofit.batch.worker import worker_resource_kinds
from tests.batch_helpers import RESOURCE_COLUMNS, resource_frame, toy_table


@pytest.fixture(autouse=True)
def _fresh():
    release_worker_resources()
    yield
    release_worker_resources()


def test_made_once_per_key_and_reused():
    made = []

    def make(tag):
        made.append(tag)
        return {"tag": tag}

    a = worker_resource("kind a", "k1", lambda: make("a1"))
    assert worker_resource("kind a", "k1", lambda: make("again")) is a
    worker_resource("kind b", "k1", lambda: make("b1"))  # kinds do not share entries
    assert made == ["a1", "b1"]
    assert worker_resource_kinds() == {"kind a": {"k1": 1}, "kind b": {"k1": 1}}


def test_the_least_recently_used_is_closed_when_pushed_out_and_on_release():
    closed = []
    for key in ("k1", "k2", "k1", "k3"):  # k1 used again: k2 is the oldest when k3 comes
        worker_resource("movie", key, lambda key=key: [key], size=2, close=closed.append)
    assert closed == [["k2"]]
    release_worker_resources("movie")
    assert sorted(map(tuple, closed)) == [("k1",), ("k2",), ("k3",)]
    assert "movie" not in worker_resource_kinds()


def test_make_must_not_return_none():
    with pytest.raises(ValueError, match="returned None"):
        worker_resource("nothing", "k", lambda: None)


def test_a_forked_process_starts_without_its_parents_resources(monkeypatch):
    closed = []
    worker_resource("movie", "k", lambda: "parent's", close=closed.append)
    monkeypatch.setattr(worker_module, "_OWNER", [-1])  # as if this were a forked child
    assert worker_resource("movie", "k", lambda: "child's") == "child's"
    assert closed == []  # the parent's are not closed by the child


@pytest.mark.parametrize("workers", [0, 2])
def test_every_item_of_a_batch_reuses_its_workers_resource(tmp_path, workers):
    out = tmp_path / "resources.csv"
    run_batch(resource_frame, {"key": "same"}, range(8), lambda f: None,
              toy_table(out, RESOURCE_COLUMNS),
              options=BatchSettings(workers=workers, progress=False))
    table = pd.read_csv(out)
    assert (table["made"] == 1).all()  # once per process, whatever the number of items
    assert (table["resource"] == "made in " + table["pid"].astype(str)).all()
