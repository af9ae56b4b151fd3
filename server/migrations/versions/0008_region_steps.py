"""Region steps (rename, erase, merge, a region's material) stored with the session, so that
undo and redo cover them after a reopen (region_steps).

Revision ID: 0008
Revises: 0007
"""
import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "region_steps",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("session_id", sa.String(32), sa.ForeignKey("sessions.id"), nullable=False),
        sa.Column("seq", sa.Integer, nullable=False),
        sa.Column("object", sa.String(200), nullable=False),
        sa.Column("before", sa.JSON, nullable=False),
        sa.Column("after", sa.JSON, nullable=False),
        sa.Column("region_before", sa.String(100), nullable=True),
        sa.Column("region_after", sa.String(100), nullable=True),
        sa.Column("undone", sa.Boolean, nullable=False),
        sa.Column("dropped", sa.Boolean, nullable=False),
        sa.Column("created", sa.DateTime(timezone=True), nullable=False),
    )
    op.create_index("ix_region_steps_session_id", "region_steps", ["session_id"])


def downgrade() -> None:
    op.drop_index("ix_region_steps_session_id", "region_steps")
    op.drop_table("region_steps")
