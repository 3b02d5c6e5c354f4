# The image of the invent-zenoh services: `invent <service>` in each container of compose.yaml.
FROM python:3.11-slim
WORKDIR /app
COPY pyproject.toml README.md ./
COPY schemas ./schemas
COPY services ./services
COPY sim_bridge ./sim_bridge
RUN pip install --no-cache-dir '.[all]'
ENTRYPOINT ["invent"]
