"""Other libraries' filters as fusionkit plugins, for side-by-side comparison.

Installed with the ``peers`` extra (``pip install "fusionkit[peers]"``) and registered through
entry points in fusionkit's ``pyproject.toml`` exactly as a third party would register them.
Each adapter maps the peer's units and frames to fusionkit's (verified against the BROAD
reference and, in ``tests/test_peers.py``, against calling the peer directly):

=================  ==========================  ==============================================
name               peer                        conventions mapped
=================  ==========================  ==============================================
``vqf``            ``vqf.VQF`` (C++, online)   rad/s, m/s^2; quaternion body->ENU
``vqf-offline``    ``vqf.offlineVQF``          same; batch only (uses future samples)
``vqf-basic``      ``vqf.BasicVQF``            same
``imufusion``      ``imufusion.Ahrs``          deg/s, g; convention set as a *property*
                                               (the ``AhrsSettings`` constructor ignores it)
``ahrs-madgwick``  ``ahrs.filters.Madgwick``   rad/s, m/s^2; body->NWU
``ahrs-mahony``    ``ahrs.filters.Mahony``     rad/s, m/s^2; body->ENU
``ahrs-ekf``       ``ahrs.filters.EKF``        frame 'NED' takes the gravity vector: acc is
                                               negated; body->NED
=================  ==========================  ==============================================

A peer sees only valid samples, judged as every fusionkit filter judges them
(:func:`fusionkit.types.sample_validity`, with ``gyr_range`` / ``acc_range``): with
``nan_policy="skip"`` a sample with an invalid gyroscope is not passed to it and the previous
orientation is held; an invalid or saturated accelerometer, or an invalid magnetometer, is left
out of that sample only (VQF's separate updates; imufusion's zero vector, which it ignores; a
gyro-only step for the ahrs filters), so the integration goes on. Timestamp gaps are held
(Flag.GAP). The offline VQF, which cannot skip, gets the last fully valid sample repeated instead.
"""

from ._base import PeerConfig, PeerFilter
from .ahrs import AhrsEkf, AhrsMadgwick, AhrsMahony
from .imufusion import ImufusionFilter
from .vqf import VqfBasic, VqfFilter, VqfOffline

__all__ = ["PeerConfig", "PeerFilter", "VqfFilter", "VqfOffline", "VqfBasic", "ImufusionFilter", "AhrsMadgwick", "AhrsMahony",
           "AhrsEkf"]
