"""What an ``--import`` module may do to the process, and how its failures are reported: a
module named like a standard-library one, helper modules it imports, its stop-signal handlers,
a Python callback of its simulator that raises; and a policy's numeric settings."""

from __future__ import annotations

import json
import signal
import sys

import pytest

from cognet_jax.checkpoint import _check_fingerprint
from cognet_jax.errors import MismatchError, callback_failure
from cognet_jax.plugins import import_plugin
from cognet_jax.registry import foreign_code
from cognet_jax.signals import install_stop_handlers, restore_stop_handlers


def test_a_module_named_like_the_standard_library_does_not_replace_it(tmp_path):
    """A user file ``json.py`` is imported under its own private name: ``json`` stays the
    standard library's (the tool wrote its results with it after the import)."""
    module = tmp_path / "json.py"
    module.write_text("VALUE = 7\n")
    import_plugin(str(module))
    assert sys.modules["json"].dumps({"a": 1}) == '{"a": 1}'
    assert sys.modules["cognet_import_json"].VALUE == 7


def test_a_module_named_like_an_installed_package_not_imported_yet_does_not_hide_it(tmp_path):
    """A user file named like an installed package the process has not imported yet (a
    ``matplotlib.py`` broke the figures after the search): imported under a private name."""
    import importlib.util

    names = ("pygments", "idna", "certifi", "docutils", "pyparsing", "cycler", "kiwisolver")
    free = [n for n in names if n not in sys.modules and importlib.util.find_spec(n)]
    if not free:
        pytest.skip("no installed package left unimported to be named like")
    module = tmp_path / f"{free[0]}.py"
    module.write_text("VALUE = 7\n")
    import_plugin(str(module))
    assert sys.modules[f"cognet_import_{free[0]}"].VALUE == 7
    assert free[0] not in sys.modules  # the installed package is still the one to import


def test_helper_modules_of_an_import_are_recorded_with_their_digests(tmp_path, monkeypatch):
    """A module that an ``--import`` file imports from beside it changes its numbers too: its
    digest is recorded with the file's (a policy then refuses a changed helper)."""
    (tmp_path / "seek_helper_x.py").write_text("HIT = 1.0\n")
    main = tmp_path / "uses_helper_x.py"
    main.write_text("import seek_helper_x\nHIT = seek_helper_x.HIT\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import_plugin(str(main))
    recorded = foreign_code()
    assert "uses_helper_x.py" in recorded and "seek_helper_x.py" in recorded


def test_a_helper_imported_only_when_the_module_runs_is_recorded_too(tmp_path, monkeypatch):
    """A helper that an ``--import`` module imports inside a function (when its simulator is
    built or traced), after its own import: recorded all the same, with its digest then."""
    (tmp_path / "late_helper_y.py").write_text("HIT = 1.0\n")
    main = tmp_path / "uses_late_helper_y.py"
    main.write_text("def build():\n    import late_helper_y\n    return late_helper_y.HIT\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import_plugin(str(main))
    assert "late_helper_y.py" not in foreign_code()
    sys.modules["uses_late_helper_y"].build()
    before = foreign_code()["late_helper_y.py"]
    (tmp_path / "late_helper_y.py").write_text("HIT = 2.0\n")
    assert foreign_code()["late_helper_y.py"] != before  # a policy then refuses the change


def test_a_late_helper_counts_where_it_was_loaded_at_both_times(tmp_path):
    """``imported_late`` (helpers a user module imported when it ran): compared where loaded
    at training and now; one the evaluation never loads never ran in it."""
    import json as js

    trained = {"numerics": {"imported": {"sim.py": "1"}, "imported_late": {"helper.py": "a"}}}
    stored = js.dumps(trained)
    unloaded = {"numerics": {"imported": {"sim.py": "1"}, "imported_late": {}}}
    _check_fingerprint(tmp_path, stored, unloaded)  # never loaded now: no difference
    changed = {"numerics": {"imported": {"sim.py": "1"}, "imported_late": {"helper.py": "b"}}}
    with pytest.raises(MismatchError, match="imported_late"):
        _check_fingerprint(tmp_path, stored, changed)
    missing = {"numerics": {"imported": {}, "imported_late": {"helper.py": "a"}}}
    with pytest.raises(MismatchError, match="sim.py"):  # the --import itself: always compared
        _check_fingerprint(tmp_path, stored, missing)


def test_stop_handlers_replaced_by_a_module_are_put_back():
    install_stop_handlers()
    before = signal.getsignal(signal.SIGTERM)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # what a module did at import
    try:
        assert restore_stop_handlers() == ["SIGTERM"]
        assert signal.getsignal(signal.SIGTERM) is before
        assert restore_stop_handlers() == []
    finally:
        signal.signal(signal.SIGTERM, before)


def test_a_failed_callback_is_reported_at_the_users_frame():
    text = (
        "INTERNAL: CpuCallback error calling callback: Traceback (most recent call last): "
        'File "/site-packages/jax/_src/callback.py", line 71, in __call__ '
        'File "/home/me/sim.py", line 45, in boom ValueError: my callback failed'
    )
    assert callback_failure(RuntimeError(text)) == (
        "/home/me/sim.py:45 in boom(): ValueError: my callback failed"
    )
    assert callback_failure(RuntimeError("shapes (2,) and (3,) differ")) is None


def test_a_numeric_setting_recorded_since_a_policy_was_written_is_no_difference(tmp_path):
    """A policy written before ``threefry_partitionable`` was recorded still evaluates; one
    written under another value is refused naming it."""
    now = {
        "numerics": {
            "x64": False,
            "prng": "threefry2x32",
            "threefry_partitionable": True,
            "imported": {},
        }
    }
    older = {"numerics": {"x64": False, "prng": "threefry2x32", "imported": {}}}
    _check_fingerprint(tmp_path, json.dumps(older), now)
    other = {"numerics": dict(now["numerics"], threefry_partitionable=False)}
    with pytest.raises(MismatchError, match="threefry_partitionable: trained False, now True"):
        _check_fingerprint(tmp_path, json.dumps(other), now)


def test_a_vae_replaced_in_a_run_folder_is_refused(tmp_path):
    """``results.json``'s ``run_files`` name the files the run kept (the VAE of an encoded
    run) with their sha256: another file in its place (trained again into the folder, or
    copied) is refused like a replaced policy."""
    import hashlib

    from cognet_jax.saved_runs import _check_digest

    vae = tmp_path / "vae.msgpack"
    vae.write_bytes(b"the run's VAE")
    digest = hashlib.sha256(vae.read_bytes()).hexdigest()
    _check_digest(vae, digest, "run_files")
    vae.write_bytes(b"another VAE")
    with pytest.raises(MismatchError, match="not the file this run wrote.*run_files"):
        _check_digest(vae, digest, "run_files")
    _check_digest(vae, None, "vae_sha256")  # a run saved before the field: nothing to compare


def test_a_keyboard_interrupt_raised_by_a_module_names_it(tmp_path, capsys):
    from cognet_jax.cli import main

    module = tmp_path / "kbint.py"
    module.write_text("raise KeyboardInterrupt\n")
    assert main(["--import", str(module), "list"]) == 2
    assert "kbint.py raised KeyboardInterrupt" in capsys.readouterr().err
