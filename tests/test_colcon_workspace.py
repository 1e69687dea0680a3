"""The src/ workspace builds with colcon as ament_python packages.

On a full ROS 2 install, ``colcon build`` then ``ros2 run <pkg> <exe>`` must
work. This test builds src/ with the venv's colcon into a temporary directory
(the repo is left untouched), then, for every console script of every package
(read from the built install tree, so new nodes are covered automatically),
resolves the executable the way ``ros2 run`` does: the ament index gives the
package prefix, the executable is ``<prefix>/lib/<pkg>/<exe>``.
"""

import importlib.metadata
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / 'src'
EXPECTED_PACKAGES = {
    'pkm_kinematics', 'pkm_common', 'pkm_trajectory', 'pkm_controller', 'pkm_sim_hw',
    'pkm_gough_sensor', 'pkm_bringup', 'pkm_recording', 'pkm_runs', 'pkm_operator', 'pkm_studies',
    'pkm_gallery', 'pkm_drives', 'pkm_calibration',
}
COLCON = [sys.executable, '-m', 'colcon']
BUILD_TIMEOUT_S = 600


def _colcon_env(tmp):
    env = dict(os.environ)
    env['PYTHONDONTWRITEBYTECODE'] = '1'  # no __pycache__ in src/ from setup.py
    env['COLCON_HOME'] = str(tmp / 'colcon_home')  # ignore ~/.colcon defaults
    return env


def _run(cmd, *, timeout=120, **kwargs):
    proc = subprocess.run(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        timeout=timeout, **kwargs)
    return proc


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    """Build src/ once for this module; returns the install base."""
    tmp = tmp_path_factory.mktemp('colcon_ws')
    cmd = COLCON + [
        '--log-base', str(tmp / 'log'),
        'build',
        '--base-paths', str(SRC),
        '--build-base', str(tmp / 'build'),
        '--install-base', str(tmp / 'install'),
    ]
    proc = _run(cmd, cwd=tmp, env=_colcon_env(tmp), timeout=BUILD_TIMEOUT_S)
    assert proc.returncode == 0, (
        f'colcon build failed ({proc.returncode}):\n{proc.stdout[-8000:]}')
    return tmp / 'install'


@pytest.fixture(scope='module')
def sourced_env(workspace):
    """The environment after ``. <install>/local_setup.sh``, as a user has."""
    setup = workspace / 'local_setup.sh'
    assert setup.is_file(), f'{setup} missing'
    proc = subprocess.run(
        ['/bin/sh', '-c', f'. "{setup}" && env -0'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, timeout=60,
        env=dict(os.environ))
    assert proc.returncode == 0, proc.stderr.decode(errors='replace')
    env = {}
    for entry in proc.stdout.split(b'\0'):
        if b'=' in entry:
            key, _, value = entry.decode(errors='surrogateescape').partition('=')
            env[key] = value
    return env


def _interpreted(env):
    """``env`` with the kernels left interpreted (pkm_kinematics.jit, PKM_NO_JIT): numba
    caches per source path, so the install tree's copy would compile every kernel on
    import (minutes on a loaded machine), and what these tests check is the packaging."""
    return {**env, 'PKM_NO_JIT': '1'}


def _console_scripts(install):
    """(package, script name, 'module:attr') for every built package."""
    scripts = []
    for pkg_prefix in sorted(p for p in install.iterdir() if p.is_dir()):
        site_dirs = list(pkg_prefix.glob('lib/python3*/site-packages'))
        for dist in importlib.metadata.distributions(path=[str(d) for d in site_dirs]):
            for ep in dist.entry_points.select(group='console_scripts'):
                scripts.append((pkg_prefix.name, ep.name, ep.value))
    return scripts


def _ros2_run_path(package, executable, ament_prefix_path):
    """Resolve like ``ros2 run``: ament index prefix, then lib/<package>/."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    old = os.environ.get('AMENT_PREFIX_PATH')
    os.environ['AMENT_PREFIX_PATH'] = ament_prefix_path
    try:
        prefix = get_package_prefix(package)
    except PackageNotFoundError:
        return None, None
    finally:
        if old is None:
            os.environ.pop('AMENT_PREFIX_PATH', None)
        else:
            os.environ['AMENT_PREFIX_PATH'] = old
    return Path(prefix), Path(prefix) / 'lib' / package / executable


def test_colcon_lists_ament_python_packages(tmp_path):
    proc = _run(
        COLCON + ['--log-base', str(tmp_path / 'log'), 'list',
                  '--base-paths', 'src'],
        cwd=REPO, env=_colcon_env(tmp_path))
    assert proc.returncode == 0, proc.stdout
    listed = {}
    for line in proc.stdout.splitlines():
        fields = line.split('\t')
        if len(fields) == 3:
            listed[fields[0]] = fields[2]
    assert EXPECTED_PACKAGES <= set(listed), proc.stdout
    not_ament = {n: t for n, t in listed.items() if t != '(ros.ament_python)'}
    # A rejected package.xml (e.g. maintainer e-mail a@b.c) silently turns a
    # package into '(python)'.
    assert not not_ament, f'not ament_python: {not_ament}\n{proc.stdout}'


def test_install_tree_has_ament_index_and_manifest(workspace):
    for pkg in sorted(EXPECTED_PACKAGES):
        prefix = workspace / pkg
        marker = prefix / 'share/ament_index/resource_index/packages' / pkg
        assert marker.is_file(), f'{marker} missing'
        assert (prefix / 'share' / pkg / 'package.xml').is_file()


def test_console_scripts_resolve_like_ros2_run(workspace, sourced_env):
    scripts = _console_scripts(workspace)
    assert ('pkm_kinematics', 'pkm-analyze') in {(p, n) for p, n, _ in scripts}

    ament_prefix_path = sourced_env.get('AMENT_PREFIX_PATH', '')
    for pkg, name, _ in scripts:
        prefix, exe = _ros2_run_path(pkg, name, ament_prefix_path)
        assert prefix == workspace / pkg, (
            f'ament index resolves {pkg} to {prefix}, not {workspace / pkg}')
        assert exe.is_file(), f'ros2 run {pkg} {name}: {exe} missing'
        assert os.access(exe, os.X_OK), f'{exe} is not executable'


def test_console_script_targets_import_from_install_tree(workspace, sourced_env):
    """Every entry point's module imports (from the built copy) and has the attr.

    Nothing is called, so nodes are not started.
    """
    targets = [value for _, _, value in _console_scripts(workspace)]
    probe = (
        'import importlib, json, sys\n'
        'out = []\n'
        'for target in json.loads(sys.argv[1]):\n'
        '    mod_name, _, attr = target.partition(":")\n'
        '    mod = importlib.import_module(mod_name.strip())\n'
        '    obj = mod\n'
        '    for part in attr.strip().split("."):\n'
        '        obj = getattr(obj, part)\n'
        '    out.append([target, mod.__file__, callable(obj)])\n'
        'print(json.dumps(out))\n'
    )
    proc = subprocess.run(
        [sys.executable, '-c', probe, json.dumps(targets)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=_interpreted(sourced_env), cwd=workspace, timeout=120)
    assert proc.returncode == 0, proc.stderr
    for target, module_file, is_callable in json.loads(proc.stdout):
        assert is_callable, f'{target} is not callable'
        assert Path(module_file).is_relative_to(workspace), (
            f'{target} imported from {module_file}, not the install tree')


def test_pkm_analyze_help_runs_from_install_tree(workspace, sourced_env):
    _, exe = _ros2_run_path(
        'pkm_kinematics', 'pkm-analyze', sourced_env.get('AMENT_PREFIX_PATH', ''))
    proc = subprocess.run(
        [str(exe), '--help'], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, env=_interpreted(sourced_env), cwd=workspace, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert 'usage' in proc.stdout.lower(), proc.stdout
