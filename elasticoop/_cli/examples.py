"""`elasticoop examples`: list the packaged example scenarios, or copy them (with
their data files) into a folder to start a study from."""

import importlib.resources
import pathlib
import shutil
import tomllib

from .._examples import example_files, example_studies
from ._common import EXIT_OK, common_options, say

NAME = "examples"


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        NAME,
        parents=[common_options()],
        help="list the example scenarios, or copy them to a folder",
        description=(
            "List the example scenario files shipped with elasticoop, and the "
            "Monte Carlo study files over them (NAME.study.toml). With --copy "
            "DIR, copy them and the data files they use into DIR, to edit and run "
            "with 'elasticoop run' and 'elasticoop montecarlo'."
        ),
    )
    parser.add_argument(
        "--copy", metavar="DIR", help="copy the example files into this folder"
    )
    parser.set_defaults(func=execute)


def execute(args) -> int:
    files = example_files()
    if args.copy:
        target = pathlib.Path(args.copy)
        target.mkdir(parents=True, exist_ok=True)
        folder = importlib.resources.files("elasticoop") / "scenarios"
        copied = []
        for item in folder.iterdir():
            if item.is_file() and not item.name.startswith(("_", ".")):
                with importlib.resources.as_file(item) as source:
                    shutil.copyfile(source, target / item.name)
                copied.append(item.name)
        say(args, f"copied {', '.join(sorted(copied))} into {target}")
        return EXIT_OK
    for name, file in files.items():
        info = tomllib.loads(file.read_text(encoding="utf-8"))
        say(args, f"{name}: {info.get('description', info.get('name', ''))}")
        say(args, f"    {file}")
    for name, file in example_studies().items():
        info = tomllib.loads(file.read_text(encoding="utf-8"))
        say(args, f"{name} (study): {info.get('description', info.get('name', ''))}")
        say(args, f"    {file}")
    return EXIT_OK
