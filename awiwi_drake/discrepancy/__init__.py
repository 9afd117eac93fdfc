"""Model-discrepancy workflow (issue 6): find where simulation and data disagree,
name the missing effect, add it to the model and show the gap shrink.

Entry points: :func:`load_dataset`, :func:`diagnose` (returns a :class:`Diagnosis`),
:func:`write_report`, :func:`make_truth_dataset` (hidden-effect test data).
See ``docs`` of each module: ``catalog`` (named effects), ``model`` (the
augmented Drake system), ``replay`` (multiple shooting), ``localise``
(residual maps), ``screen``, ``fit``, ``decide`` (acceptance, materiality,
separability), ``workflow`` (the loop), ``result`` (result types), ``truth``
(generator).
"""

from .augment import AugmentedParameters, augmented_rig_parameters
from .catalog import EFFECTS, NUISANCE_EFFECTS, PHYSICAL_EFFECTS
from .data import RIGS, Dataset, load_dataset, save_dataset
from .model import DiscrepancyModel_, NominalParameters
from .replay import ReplayEngine
from .truth import HIDDEN_EFFECTS, HiddenEffectPlant_, make_truth_dataset
from .result import Diagnosis
from .workflow import DiagnosisInterrupted, diagnose, gap_metrics


def write_report(dx, directory, *, figures: bool = True):
    """Write the report folder (see :mod:`awiwi_drake.discrepancy.report`)."""
    from .report import write_report as _w
    return _w(dx, directory, figures=figures)


__all__ = ["EFFECTS", "PHYSICAL_EFFECTS", "NUISANCE_EFFECTS", "RIGS", "Dataset", "load_dataset",
           "save_dataset", "DiscrepancyModel_", "NominalParameters", "ReplayEngine", "HIDDEN_EFFECTS",
           "HiddenEffectPlant_", "make_truth_dataset", "Diagnosis", "DiagnosisInterrupted", "diagnose", "gap_metrics",
           "write_report", "AugmentedParameters", "augmented_rig_parameters"]
