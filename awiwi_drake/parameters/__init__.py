"""All parameter sets of awiwi_drake, with units, ranges and sources.

Defaults are the Awiwi hand's; every value cites the thesis or says why it was chosen.
"""

from awiwi_drake.parameters.base import ParameterInfo, Parameters, param, provenance_table
from awiwi_drake.parameters.components import (
    GuideFrictionParams, HysteresisParams, LinearSpringParams, MotorParams, PolynomialSpringParams,
    SpringMechanismGeometry, TendonGuideParams, TendonParams)
from awiwi_drake.parameters.rigs import (
    DemoScenario, FlexibleJointParams, JointRigParams, MotorPositionGains, SpringModelParams, TendonRigParams)
from awiwi_drake.parameters.control import (
    CompareTestParams, ForceSensorParams, FrictionIdentificationParams, ImpedanceParams, LqrParams, PolePlacementParams,
    RippleCompensationParams, SdreJointParams, SdreTendonParams, TendonForceGains)
from awiwi_drake.parameters.wrist import WristParams
from awiwi_drake.parameters.hand import (
    FifthFingerParams, FingerParams, FingerRigParams, HandParams, HandRigParams, IndexFingerParams,
    JointControllerParams, MiddleFingerParams, RingFingerParams, ThumbParams)
from awiwi_drake.parameters.backstepping import (
    AntagonisticBacksteppingGains, BacksteppingPlantParams, ImpedanceBacksteppingGains, ImpedanceStudy,
    NonlinearImpedanceStudy, OptimalGainsCase, OptimalGainsStudy, PipStudy, PositionBacksteppingGains,
    PositionStudy, ScalarExampleGains)
from awiwi_drake.parameters.hand_control import (
    ForceDistributionParams, FrictionObserverParams, LinkFrictionParams, StiffnessCorrectionParams)
from awiwi_drake.parameters.joint_design import JointDesignParams
from awiwi_drake.parameters.discrepancy import CatalogBounds, DiscrepancySettings, TruthGeneratorParams
from awiwi_drake.parameters.cli import AnimationParams, CliLimits, CompareShortMode
