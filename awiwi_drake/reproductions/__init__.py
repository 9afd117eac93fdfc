"""The thesis's studies and experiments, one module per chapter (results are data, plots sit beside them).

Each module rebuilds the runs behind a chapter's figures from the package's
plants (:mod:`awiwi_drake.rigs`, :mod:`awiwi_drake.hand`), controllers
(:mod:`awiwi_drake.control`) and framework wrappers (:mod:`awiwi_drake.analysis`),
and returns data; its ``plot_*`` functions draw that data. docs/REPRODUCTIONS.md
records each figure: the printed value, ours, the verdict.

=============================================  =========================================
thesis                                         module
=============================================  =========================================
ch. 3 motor: friction (Fig 3.3), ripple        :mod:`.ch03_motor`
ch. 5 fingers: Coriolis (Fig 5.7), poles       :mod:`.ch05_fingers`
ch. 5.5 fifth finger HMC four-bar vs revolute  :mod:`.ch05_fifth_hmc`
ch. 6 wrist: finger drift under wrist motion   :mod:`.ch06_wrist`
ch. 5/7/8 stiffness by co-contraction, closed  :mod:`.ch07_cocontraction`
ch. 8 stiffness correction (Fig 8.3)           :mod:`.ch08_stiffness_correction`
ch. 9 friction observer (Fig 9.3)              :mod:`.ch09_friction_observer`
ch. 10 tendon force control (Fig 10.1-10.3)    :mod:`.ch10_tendon_force`
ch. 11 impedance control (Fig 11.2-11.4)       :mod:`.ch11_impedance`
ch. 12 pole placement (Fig 12.3-12.4, (12.19)) :mod:`.ch12_pole_placement`
ch. 13 LQR (Fig 13.2-13.3)                     :mod:`.ch13_lqr`
ch. 14 SDRE (Fig 14.3-14.5)                    :mod:`.ch14_sdre`
ch. 15 backstepping (Fig 15.2-15.27)           :mod:`.ch15_backstepping`, :mod:`.ch15_scalar_example`,
                                               :mod:`.ch15_pip_experiments` (Fig 15.24-15.25 on a PIP)
ch. 15 PIP of a finger (Fig 15.24-15.25)       :mod:`.ch15_pip_experiments`
ch. 16 optimal backstepping gains (Tab 16.1)   :mod:`.ch16_optimal_backstepping`
``awiwi-drake demo`` (joint rig)               :mod:`.demo`
invented parameters (figure sensitivity)      :mod:`.invented_parameters`
=============================================  =========================================

Modules are imported on demand (``from awiwi_drake.reproductions import ch15_backstepping``).
"""
