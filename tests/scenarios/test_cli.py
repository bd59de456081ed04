from typer.testing import CliRunner

from h4bench.scenarios.cli import app


def test_help_and_version():
    runner = CliRunner()
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0 and "version" in result.output
    result = runner.invoke(app, ["version"])
    assert result.exit_code == 0 and "mujoco 4." in result.output
