"""One name for one thing across every command: ``-o/--out`` for where results go
(``--output`` still accepted, not shown), and the shared options declared once."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.cli.options import AliasedOption, duration_option, out_option


def _commands(group: click.Command, prefix: str = "rfsas") -> Iterator[tuple[str, click.Command]]:
    if isinstance(group, click.Group):
        for name, sub in group.commands.items():
            yield from _commands(sub, f"{prefix} {name}")
    else:
        yield prefix, group


@pytest.fixture(scope="module")
def commands() -> list[tuple[str, click.Command]]:
    _load_commands()
    return list(_commands(cli))


def test_every_output_option_is_called_out(commands: list[tuple[str, click.Command]]) -> None:
    ctx = click.Context(cli)
    outs = []
    for name, command in commands:
        for param in command.params:
            if not isinstance(param, click.Option):
                continue
            record = param.get_help_record(ctx)
            shown = record[0] if record else ""
            assert "--output" not in shown, f"{name}: {shown}"
            if "--output" in param.opts:
                assert "--out" in param.opts and "--out" in shown, f"{name}: {param.opts}"
                outs.append(name)
    # replay, live, backend, export, calibrate, demo, sim capture, keys new/export, …
    assert len(outs) >= 12, outs


def test_the_old_name_still_works(tmp_path: Path) -> None:
    @click.command()
    @out_option("Where the result goes.")
    @duration_option()
    def command(out: Path | None, duration: float | None) -> None:
        click.echo(f"{out} {duration}")

    runner = CliRunner()
    for flag in ("-o", "--out", "--output"):
        result = runner.invoke(command, [flag, str(tmp_path / "x.jsonl"), "--duration", "2"])
        assert result.exit_code == 0, result.output
        assert result.output.strip() == f"{tmp_path / 'x.jsonl'} 2.0"
    shown = runner.invoke(command, ["--help"]).output
    assert "-o, --out FILE" in shown and "--output" not in shown
    refused = runner.invoke(command, ["--duration", "0"])
    assert refused.exit_code == 2 and "--duration" in refused.output


def test_aliases_are_hidden_only_from_help() -> None:
    option = AliasedOption(["-o", "--out", "--output", "out"], hidden_aliases=("--output",))
    record = option.get_help_record(click.Context(click.Command("x")))
    assert record is not None and "--output" not in record[0]
    assert option.opts == ["-o", "--out", "--output"]  # still parsed


def test_every_option_says_what_it_is(commands: list[tuple[str, click.Command]]) -> None:
    silent = [
        (name, param.opts[-1])
        for name, command in commands
        for param in command.params
        if isinstance(param, click.Option) and not param.hidden and not param.help
    ]
    assert silent == []
