"""`elasticoop examples`: list the packaged example scenarios, or copy them (with
their data files) into a folder to start a study from."""

import importlib.resources
import pathlib
import shutil
import tomllib

from .._examples import example_files, example_studies
from ._common import EXIT_OK, UserError, common_options, say

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
            "with 'elasticoop run' and 'elasticoop montecarlo'. A file of DIR that "
            "differs from the example of that name (one you edited) is never "
            "replaced without --overwrite: the copy is refused, naming the files, "
            "and nothing is copied."
        ),
    )
    parser.add_argument(
        "--copy", metavar="DIR", help="copy the example files into this folder"
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="with --copy: replace files of DIR that differ from the examples",
    )
    parser.set_defaults(func=execute)


def execute(args) -> int:
    files = example_files()
    if args.copy:
        copy_examples(pathlib.Path(args.copy), args)
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


def copy_examples(target: pathlib.Path, args) -> None:
    """Copy the packaged scenario files and their data files into `target`; a file
    already there with the same content is left alone, one that differs is
    replaced only with `--overwrite` (else `UserError` names them all)."""
    folder = importlib.resources.files("elasticoop") / "scenarios"
    items = sorted(
        (item for item in folder.iterdir() if item.is_file()),
        key=lambda item: item.name,
    )
    items = [item for item in items if not item.name.startswith(("_", "."))]
    changed = [
        item.name
        for item in items
        if (target / item.name).exists()
        and (target / item.name).read_bytes() != item.read_bytes()
    ]
    if changed and not args.overwrite:
        raise UserError(
            f"--copy: {target} already holds {len(changed)} file"
            f"{'s' if len(changed) != 1 else ''} that differ from the examples "
            f"(edited?): {', '.join(changed)}; nothing was copied. Copy into another "
            f"folder, or add --overwrite to replace them"
        )
    target.mkdir(parents=True, exist_ok=True)
    copied, same = [], []
    for item in items:
        destination = target / item.name
        if destination.exists() and destination.read_bytes() == item.read_bytes():
            same.append(item.name)
            continue
        with importlib.resources.as_file(item) as source:
            shutil.copyfile(source, destination)
        copied.append(item.name)
    if copied:
        say(args, f"copied {', '.join(copied)} into {target}")
    if same:
        say(args, f"already there, unchanged: {', '.join(same)}")
