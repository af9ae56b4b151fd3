"""Sessions shared across API processes: which processes serve a session's streams
(session_servers) and the messages they store while several do (session_log).

Revision ID: 0007
Revises: 0006
"""
import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "session_servers",
        sa.Column("session_id", sa.String(32), sa.ForeignKey("sessions.id"), primary_key=True),
        sa.Column("origin", sa.String(32), primary_key=True),
        sa.Column("seen", sa.DateTime(timezone=True), nullable=False),
        sa.Column("peers", sa.JSON, nullable=False),
    )
    op.create_table(
        "session_log",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("session_id", sa.String(32), sa.ForeignKey("sessions.id"), nullable=False),
        sa.Column("seq", sa.Integer, nullable=False),
        sa.Column("origin", sa.String(32), nullable=False),
        sa.Column("body", sa.JSON, nullable=False),
        sa.Column("created", sa.DateTime(timezone=True), nullable=False),
        sa.UniqueConstraint("session_id", "seq"),
    )
    op.create_index("ix_session_log_session_id", "session_log", ["session_id"])
    op.create_index("ix_session_log_created", "session_log", ["created"])


def downgrade() -> None:
    op.drop_index("ix_session_log_created", "session_log")
    op.drop_index("ix_session_log_session_id", "session_log")
    op.drop_table("session_log")
    op.drop_table("session_servers")
