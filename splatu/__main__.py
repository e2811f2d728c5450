from splatu.cli import entrypoint

entrypoint()
