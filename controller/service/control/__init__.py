"""The parts of the controller (`controller.service.loop.Controller`), one module each."""
