"""evalkit, the CLI and the pure blendgen modules must work without Blender."""

import subprocess
import sys

PURE = [
    "cli",
    "evalkit",
    "evalkit.dataset",
    "evalkit.registry",
    "evalkit.metrics.core",
    "evalkit.runner",
    "evalkit.reports.tables",
    "blendgen.geometry",
    "blendgen.config.models",
    "blendgen.markers",
    "blendgen.vehicle.trajectories",
    "blendgen.pipeline.plan",
    "blendgen.pipeline.groundtruth",
    "blendgen.pipeline.compose",
    "blendgen.pipeline.writer",
    "blendgen.pipeline.generate",
    "blendgen.pipeline.executor",
    "blendgen.physics.water.optics",
    "blendgen.tools.apps.reproduce",
    "blendgen.tools.bench.fidelity",
    "blendgen.tools.calibration.camera",
    "evalkit.isolation",
    "evalkit.external",
    "evalkit.preprocess",
    "evalkit.localizers.hybrid",
    "evalkit.reports.results",
    "evalkit.reports.leaderboard",
    "evalkit.reports.bop",
    "evalkit.metrics.recall",
    "evalkit.metrics.extra",
    "evalkit.reports.provenance",
    "evalkit.reports.outdir",
]


def test_pure_modules_never_import_bpy():
    code = (
        "import sys, importlib\n"
        f"for m in {PURE!r}: importlib.import_module(m)\n"
        "bad = [m for m in ('bpy', 'mathutils', 'OpenImageIO') if m in sys.modules]\n"
        "print(bad); sys.exit(1 if bad else 0)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_evaluation_cli_help_without_bpy():
    # a poisoned bpy on the path proves the evaluation commands never import it
    code = (
        "import sys, types\n"
        "class Boom(types.ModuleType):\n"
        "    def __getattr__(self, k): raise RuntimeError('bpy imported')\n"
        "sys.modules['bpy'] = Boom('bpy')\n"
        "import cli\n"
        "from click.testing import CliRunner\n"
        "for cmd in (['evaluate', '--help'], ['localizers'], ['verify', '--help']):\n"
        "    r = CliRunner().invoke(cli.main, cmd)\n"
        "    assert r.exit_code == 0, (cmd, r.output, r.exception)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
