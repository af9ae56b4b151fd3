"""Lighting captures: a zip of fisheye brackets processed as a job into an
environment-map asset.

Revision ID: 0003
Revises: 0002
"""
import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table("captures",
                    sa.Column("id", sa.String(32), primary_key=True),
                    sa.Column("status", sa.String(16), nullable=False),
                    sa.Column("progress", sa.Float, nullable=False),
                    sa.Column("message", sa.String(1000), nullable=False),
                    sa.Column("zip_sha256", sa.String(64), nullable=False),
                    sa.Column("asset_id", sa.String(32), sa.ForeignKey("assets.id"), nullable=True),
                    sa.Column("preview_sha256", sa.String(64), nullable=True),
                    sa.Column("stats", sa.JSON, nullable=False),
                    sa.Column("created", sa.DateTime(timezone=True), nullable=False),
                    sa.Column("updated", sa.DateTime(timezone=True), nullable=False))


def downgrade() -> None:
    op.drop_table("captures")
