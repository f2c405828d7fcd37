"""
The ROS-free model core: friction laws, footprint geometry, wrenches, integrators.

Split the way scipy's ``integrate/_ivp`` is: ``layout`` (the arrays' columns),
``friction``, ``geometry`` and ``wrench`` (the friction force and moment integrated
over the footprint), ``dopri`` (the one Dormand-Prince step driver), ``events``
(records, events and contact bookkeeping every method shares), ``stick`` (the limit
set, the gauge and the break-away time), ``breakaway`` (the pull direction and the
boundary layer after a break), ``approach`` (the slip's last stretch before a stick),
one module per method (``accurate``, ``implicit``, ``threshold``), ``simulate`` (the
Python front with its result object), ``cell_kernels`` (many parcels per period) and
``oscillator`` (the Fig. 4 body). ``cache`` keeps numba's on-disk cache honest.

Nothing under this package imports rclpy or any message module (a test enforces it),
and importing it has no side effects.
"""
