"""Pose models (torch, no ROS); :mod:`~audio2pose_ros.models.registry` maps a name to its class.

=============== ===================================== ================================
name            seed                                  streams
=============== ===================================== ================================
``mlp``         003 section 4.3.3                     yes
``lstm``        003 section 4.3.4                     yes (state carried)
``dae_gru``     000 sections 4.3-4.5                  no (centred 61-frame context)
``blstm``       002 section 3.1                       no
``blstm_prior`` 002 section 3.2                       no
``cvae``        002 section 3.3                       no (samples)
``live``        ours                                  yes (samples)
``live_groups`` ours: a live sampler per joint group  yes (samples)
=============== ===================================== ================================

Importing this package imports nothing: the numpy parts (:mod:`~audio2pose_ros.models.speech_gate`,
:mod:`~audio2pose_ros.models.recurrent_numpy`) load without torch.
"""
