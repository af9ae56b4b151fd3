"""The schema of release 0.3 (created then by create_all).

Revision ID: 0001
Revises:
"""
import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None

TS = sa.DateTime(timezone=True)


def upgrade() -> None:
    op.create_table("assets",
                    sa.Column("id", sa.String(32), primary_key=True), sa.Column("kind", sa.String(16), nullable=False),
                    sa.Column("filename", sa.String(255), nullable=False),
                    sa.Column("sha256", sa.String(64), nullable=False, index=True),
                    sa.Column("size", sa.Integer, nullable=False), sa.Column("meta", sa.JSON, nullable=False),
                    sa.Column("created", TS, nullable=False))
    op.create_table("scenes",
                    sa.Column("id", sa.String(32), primary_key=True), sa.Column("name", sa.String(255), nullable=False),
                    sa.Column("spec", sa.JSON, nullable=False), sa.Column("created", TS, nullable=False))
    op.create_table("precomputations",
                    sa.Column("id", sa.String(32), primary_key=True),
                    sa.Column("scene_id", sa.String(32), sa.ForeignKey("scenes.id"), nullable=False, index=True),
                    sa.Column("status", sa.String(16), nullable=False), sa.Column("progress", sa.Float, nullable=False),
                    sa.Column("message", sa.String(1000), nullable=False),
                    sa.Column("cuts_sha256", sa.String(64), nullable=True), sa.Column("stats", sa.JSON, nullable=False),
                    sa.Column("created", TS, nullable=False), sa.Column("updated", TS, nullable=False))
    op.create_table("materials",
                    sa.Column("id", sa.String(32), primary_key=True), sa.Column("name", sa.String(255), nullable=False),
                    sa.Column("scene_id", sa.String(32), nullable=True), sa.Column("object", sa.String(255), nullable=True),
                    sa.Column("archived", sa.Boolean, nullable=False), sa.Column("created", TS, nullable=False))
    op.create_table("material_versions",
                    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
                    sa.Column("design_id", sa.String(32), sa.ForeignKey("materials.id"), nullable=False, index=True),
                    sa.Column("version", sa.Integer, nullable=False), sa.Column("body", sa.JSON, nullable=False),
                    sa.Column("note", sa.String(1000), nullable=False), sa.Column("created", TS, nullable=False),
                    sa.UniqueConstraint("design_id", "version"))
    op.create_table("sessions",
                    sa.Column("id", sa.String(32), primary_key=True),
                    sa.Column("scene_id", sa.String(32), sa.ForeignKey("scenes.id"), nullable=False, index=True),
                    sa.Column("token_sha256", sa.String(64), nullable=False), sa.Column("state", sa.JSON, nullable=False),
                    sa.Column("closed", sa.Boolean, nullable=False), sa.Column("created", TS, nullable=False),
                    sa.Column("updated", TS, nullable=False))
    op.create_table("strokes",
                    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
                    sa.Column("session_id", sa.String(32), sa.ForeignKey("sessions.id"), nullable=False, index=True),
                    sa.Column("epoch", sa.Integer, nullable=False), sa.Column("seq", sa.Integer, nullable=False),
                    sa.Column("body", sa.JSON, nullable=False), sa.Column("undone", sa.Boolean, nullable=False),
                    sa.Column("dropped", sa.Boolean, nullable=False), sa.Column("created", TS, nullable=False))
    op.create_table("publications",
                    sa.Column("id", sa.String(32), primary_key=True), sa.Column("name", sa.String(255), nullable=False),
                    sa.Column("scene_id", sa.String(32), sa.ForeignKey("scenes.id"), nullable=False),
                    sa.Column("object", sa.String(255), nullable=False), sa.Column("variants", sa.JSON, nullable=False),
                    sa.Column("environments", sa.JSON, nullable=False), sa.Column("created", TS, nullable=False))
    op.create_table("api_tokens",
                    sa.Column("id", sa.String(32), primary_key=True), sa.Column("name", sa.String(255), nullable=False),
                    sa.Column("token_sha256", sa.String(64), nullable=False, unique=True),
                    sa.Column("revoked", sa.Boolean, nullable=False), sa.Column("created", TS, nullable=False))


def downgrade() -> None:
    for t in ("api_tokens", "publications", "strokes", "sessions", "material_versions", "materials",
              "precomputations", "scenes", "assets"):
        op.drop_table(t)
