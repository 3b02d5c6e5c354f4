"""The service runtime every service stands on, in layers (docs/architecture.md):

- :mod:`~services.runtime.session`: the zenoh session (configuration, opening, signals);
- :mod:`~services.runtime.logs`: logging, and the one rate-limited log and bad-input count;
- :mod:`~services.runtime.inputs`: publishers, and the inputs with their :class:`Delivery` modes;
- :mod:`~services.runtime.executor`: the one thread that handles a service's events and inputs;
- :mod:`~services.runtime.node`: a service's presence on zenoh, and the life of a reactive service.
"""
