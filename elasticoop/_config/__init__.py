"""Scenario files: the TOML schema, its validation and loading."""

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
