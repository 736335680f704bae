"""Scenario files: the TOML schema, its validation and loading.

The names are imported on first use: loading a scenario does not import the readers
of study files and measured data (which need xarray, scipy and the identification
layer).
"""

import typing

from .._lazy import lazy_attributes as _lazy_attributes

if typing.TYPE_CHECKING:
    from .build import build_scenario as build_scenario, load_scenario as load_scenario
    from .measured_data import load_experiment as load_experiment
    from .problems import (
        DataFileError as DataFileError,
        DataProblem as DataProblem,
        Problem as Problem,
        ScenarioError as ScenarioError,
    )
    from .study_file import (
        StudyFile as StudyFile,
        StudyFileError as StudyFileError,
        load_study as load_study,
    )

__getattr__, __dir__ = _lazy_attributes(__name__, __file__)
